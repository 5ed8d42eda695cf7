"""The structure-of-arrays pose pass (mara_mjx/envs/fused_pose.py) against LeanArm.pose.

Both backends (XLA's fusion of the jnp graph, and the Pallas kernel run by Pallas's
interpreter on the CPU) on random configurations inside the joint limits and on
near-contact ones (bisected to a pair's contact, then moved by 1e-6 to 3e-3 rad)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mara_mjx
from mara_mjx.envs.fused_pose import fused_pose, soa_distances, soa_pose
from mara_mjx.envs.lean import LeanArm

TOL = 1e-5  # m for positions, unitless for quaternions
BAND = 1e-6  # m: a collided bit may differ where the smallest signed distance is this close to 0


@pytest.fixture(scope="module")
def case():
    """The lean pass, 4,096 random + 1,024 near-contact configurations, the reference poses
    and each configuration's smallest signed pair distance."""
    env = mara_mjx.make("MARACollisionOrient", driver="train")
    lean = LeanArm.from_model(env.arm.mj_model)
    lower, upper = env.joint_lower, env.joint_upper

    def smallest(q):
        cc, cb = lean.distances(q)
        return jnp.minimum(jnp.min(cc), jnp.min(cb))

    dmin = jax.jit(jax.vmap(smallest))
    rng = np.random.default_rng(5)
    random = rng.uniform(lower, upper, (4096, 6)).astype(np.float32)
    # near contact: from a free to a colliding configuration, bisected (24 halvings)
    penetrating = np.asarray(dmin(random)) < 0
    free, hit = random[~penetrating], random[penetrating]
    n = min(1024, len(free), len(hit))
    lo, hi = free[:n].astype(np.float64), hit[:n].astype(np.float64)
    for _ in range(24):
        mid = (0.5 * (lo + hi)).astype(np.float32)
        f = np.asarray(dmin(mid))[:, None] < 0
        hi, lo = np.where(f, mid, hi), np.where(f, lo, mid)
    step = rng.normal(size=(n, 6)) * 10.0 ** rng.uniform(-6, -2.5, (n, 1))
    near = np.clip(0.5 * (lo + hi) + step, lower, upper).astype(np.float32)
    qs = np.concatenate([random, near])
    ref = jax.jit(jax.vmap(lean.pose))(qs)
    return lean, qs, ref, np.asarray(dmin(qs))


def _check(case, tcp, quat, hit, rows=slice(None)):
    """tcp, quat within TOL of the reference; collided equal outside the 1e-6 m band.
    Returns (configurations within the band, collided fraction)."""
    _, _, ref, dmin = case
    np.testing.assert_allclose(tcp, ref.tcp_pos[rows], atol=TOL, rtol=0)
    np.testing.assert_allclose(quat, ref.tcp_quat[rows], atol=TOL, rtol=0)
    assert np.all(np.asarray(quat)[:, 0] >= 0)
    ambiguous = np.abs(dmin[rows]) <= BAND
    want = np.asarray(ref.collided[rows])
    assert np.asarray(hit).dtype == bool
    assert int(np.sum((np.asarray(hit) != want) & ~ambiguous)) == 0
    return int(ambiguous.sum()), float(want.mean())


def test_near_contact_configurations_are_near(case):
    """The bisected set spans the bands around contact (else the test below is weak)."""
    dmin = np.abs(case[3][4096:])
    assert np.sum(dmin < 1e-4) > 200 and np.sum(dmin < 1e-5) > 20 and np.sum(dmin > 1e-4) > 20


def test_jnp_backend_matches_lean_pose(case):
    """fused_pose (jnp) on all 5,120 configurations; soa_pose's optional Jacobian and
    soa_distances against the reference's too."""
    lean, qs, ref, _ = case

    @jax.jit
    def run(q):
        cols = tuple(q[:, i] for i in range(6))
        jac = soa_pose(lean, cols, jac=True)[3]
        jac = jnp.stack([jnp.stack(row, -1) for row in jac], 1)
        return fused_pose(lean, q), jac, jnp.stack(soa_distances(lean, cols), -1)

    (tcp, quat, hit), jac, dist = run(qs)
    ambiguous, fraction = _check(case, tcp, quat, hit)
    assert 0.2 < fraction < 0.8 and ambiguous < 0.05 * len(qs)
    np.testing.assert_allclose(jac, ref.tcp_jac, atol=TOL, rtol=0)
    cc, cb = jax.jit(jax.vmap(lean.distances))(qs)
    np.testing.assert_allclose(dist, np.concatenate([cc, cb], 1), atol=TOL, rtol=0)


@pytest.mark.parametrize("n", [512, 300])
def test_pallas_interpret_matches_lean_pose(case, n):
    """The Pallas kernel (interpreted), blocks of 128: n a multiple of the block, and not
    (padded); half random and half near-contact configurations."""
    lean, qs, _, _ = case
    rows = np.r_[0 : n // 2, 4096 : 4096 + n - n // 2]
    run = jax.jit(lambda q: fused_pose(lean, q, block=128, backend="pallas", interpret=True))
    tcp, quat, hit = run(qs[rows])
    assert tcp.shape == (n, 3) and quat.shape == (n, 4) and hit.shape == (n,)
    _check(case, tcp, quat, hit, rows)


ELEMENTWISE = {
    "add", "sub", "mul", "div", "neg", "max", "min", "abs", "sqrt", "sin", "cos", "sign",
    "select_n", "lt", "le", "gt", "ge", "eq", "ne", "and", "or", "not",
    "convert_element_type", "broadcast_in_dim", "integer_pow", "square",
}  # fmt: skip


def test_soa_pose_is_one_elementwise_graph(case):
    """Only elementwise primitives on (B,) arrays (broadcasts of scalars aside) and no
    captured array constants: what a Pallas kernel body and one XLA loop fusion take."""
    lean = case[0]
    q = tuple(jnp.zeros(8, jnp.float32) for _ in range(6))
    closed = jax.make_jaxpr(lambda *q: soa_pose(lean, q, jac=True))(*q)
    assert not closed.consts
    eqns = list(closed.jaxpr.eqns)
    while eqns:
        eqn = eqns.pop()
        if eqn.primitive.name in ("jit", "pjit"):  # jnp.where and friends: look inside
            assert not eqn.params["jaxpr"].consts
            eqns += eqn.params["jaxpr"].jaxpr.eqns
            continue
        assert eqn.primitive.name in ELEMENTWISE, eqn
        for v in (*eqn.invars, *eqn.outvars):
            assert v.aval.shape in ((), (8,)), eqn
    with pytest.raises(ValueError, match="power of 2"):
        fused_pose(lean, jnp.zeros((8, 6)), block=100, backend="pallas", interpret=True)


def test_pallas_kernel_lowers_to_triton_for_a_gpu(case):
    """Cross-lowering for CUDA on the CPU (no GPU needed): every primitive of the kernel
    has a Triton lowering rule, and the call is one Triton custom call (not Mosaic GPU,
    where a bare pallas_call goes). Triton's own compilation to PTX is not run here."""
    lean = case[0]
    run = jax.jit(lambda q: fused_pose(lean, q, backend="pallas", soa=True))
    q = tuple(jax.ShapeDtypeStruct((4096,), jnp.float32) for _ in range(6))
    text = run.trace(q).lower(lowering_platforms=("cuda",)).as_text()
    assert text.count("__gpu$xla.gpu.triton") == 1 and "mosaic" not in text.lower()


def test_the_fused_kinematics_steps_the_env_as_the_lean_pass_does():
    # EnvConfig(kinematics="fused"): the batched train-driver step (vmap(env.step) with its
    # auto-reset) through arm_pose, against the default 'lean', from the same states and
    # actions: the same collisions and resets, observations to float32 rounding
    from mara_mjx.bench.env import make_step_body
    from mara_mjx.envs.batched import BatchedEnv

    out = {}
    for kin in ("lean", "fused"):
        benv = BatchedEnv(mara_mjx.make("MARACollisionOrient", kinematics=kin), 64)
        body = make_step_body(benv)
        run = jax.jit(lambda s, k, b=body: jax.lax.scan(b, (s, k), None, length=40))
        (state, _), collided = run(jax.jit(benv.reset)(jax.random.key(0)), jax.random.key(1))
        out[kin] = state, np.asarray(collided)
    (lean, hit_lean), (fused, hit_fused) = out["lean"], out["fused"]
    assert hit_lean.max() > 0  # random targets collide: the bit is exercised
    np.testing.assert_array_equal(hit_fused, hit_lean)
    np.testing.assert_array_equal(np.asarray(fused.env_state.step), np.asarray(lean.env_state.step))
    np.testing.assert_allclose(np.asarray(fused.obs), np.asarray(lean.obs), atol=1e-4)
    with pytest.raises(ValueError, match="kinematics=.*choose among"):
        from mara_mjx.bench.limit import LimitConfig

        LimitConfig(kinematics=("fast",))


def test_the_bench_counts_kernels_and_checks_reset_strategies():
    # `benchmark limit`'s kernel count: the launching instructions outside fused computations;
    # an elementwise chain is one fusion, and a reduction after it adds at least one more
    from mara_mjx.bench.limit import LimitConfig, kernel_count

    x = jnp.ones(64)
    one = kernel_count(jax.jit(lambda x: jnp.sin(x) * 2 + 1).lower(x).compile().as_text())
    more = kernel_count(
        jax.jit(lambda x: jnp.sin(x) * jnp.sum(jnp.cos(x) ** 2)).lower(x).compile().as_text()
    )
    assert one >= 1 and more > one
    with pytest.raises(ValueError, match="reset_strategies=.*choose among"):
        LimitConfig(reset_strategies=("lazy",))
