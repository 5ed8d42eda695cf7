"""The four tasks: jitted smoke with retrace guards, observation layout, rules, errors."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import FAST_COMPILE_FLAGS, TASK_NAMES, jitted

import mara_mjx
from mara_mjx.envs.base import DEFAULT_TARGET_POS, METRIC_KEYS

DATA = Path(__file__).resolve().parent / "data"

TABLE_FOLD = jnp.array([0.0, 2.0, 0.0, 0.0, 0.0, 0.0])
SPEC_REACH = jnp.array([1.3338, -1.5341, -0.7833, 0.0, 2.3903, -0.237])
TCP_AT_ZERO = np.array([-0.00105369, 0.0, 1.77419069])


def test_registered_names():
    assert set(TASK_NAMES) <= set(mara_mjx.registered())


def test_every_task_jits_resets_and_steps(task):
    env = task.env
    assert isinstance(env, mara_mjx.Env)  # the contract every consumer relies on
    layout = env.observation_layout
    assert [p["name"] for p in layout][:2] == ["q", "e"] and layout[-1]["name"] == "v"
    assert env.observation_size == layout[-1]["stop"]
    state = task.reset(jax.random.key(0))
    assert isinstance(state, mara_mjx.EnvStateLike)
    assert state.obs.shape == (env.observation_size,)
    assert set(state.metrics) == set(METRIC_KEYS)
    for i in range(3):
        state = task.step(state, SPEC_REACH + 0.01 * (2 - i))
    assert int(state.step) == 3
    assert np.all(np.isfinite(np.asarray(state.obs)))
    assert float(state.metrics["distance"]) < 0.005
    assert not bool(state.terminated) and not bool(state.truncated)
    # same structure and dtypes from reset on (no retrace: the guard would raise)
    s0 = task.reset(jax.random.key(1))
    assert jax.tree.structure(s0) == jax.tree.structure(state)
    for a, b in zip(jax.tree.leaves(s0), jax.tree.leaves(state), strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape


def test_observation_layout_against_spec(task):
    env = task.env
    state = task.reset(jax.random.key(0))
    obs = np.asarray(state.obs)
    target = np.asarray(DEFAULT_TARGET_POS)
    np.testing.assert_allclose(obs[:6], 0.0)  # q
    np.testing.assert_allclose(obs[6:9], TCP_AT_ZERO - target, atol=1e-5)  # e
    if env.task.orientation:
        assert env.observation_size == 16
        # TCP quat (1,0,0,0) (x) conj((0, .7071, .7071, 0)) = (0, -.7071, -.7071, 0)
        np.testing.assert_allclose(obs[9:13], [0, -0.7071068, -0.7071068, 0], atol=1e-6)
        assert float(state.metrics["angle"]) == pytest.approx(np.pi, abs=1e-4)
    else:
        assert env.observation_size == 12
    np.testing.assert_allclose(obs[-3:], 0.0)  # v at rest
    # after a step: q is the command, v = J(q) (q' - q) / dt
    s1 = task.step(state, SPEC_REACH)
    obs1 = np.asarray(s1.obs)
    np.testing.assert_allclose(obs1[:6], SPEC_REACH, atol=1e-6)
    d = env.arm.mj_data(np.asarray(SPEC_REACH))
    import mujoco

    jacp = np.zeros((3, 6))
    mujoco.mj_jacSite(env.arm.mj_model, d, jacp, None, env.arm.tcp_site)
    v = jacp @ (np.asarray(SPEC_REACH) / env.config.control_dt)
    np.testing.assert_allclose(obs1[-3:], v, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(obs1[6:9], d.site_xpos[env.arm.tcp_site] - target, atol=2e-5)


def test_reward_at_target_is_near_max(orient):
    s = orient.step(orient.reset(jax.random.key(0)), SPEC_REACH)
    assert float(s.reward) > 9.9
    assert np.all(np.asarray(s.metrics["position_error"]) < 1e-4)
    assert np.all(np.asarray(s.metrics["orientation_error"]) < 2e-3)


def test_collision_resets_pose_and_penalises_only_collision_tasks():
    for name, penalised in [("MARA", False), ("MARACollision", True)]:
        j = jitted(name)
        s0 = j.reset(jax.random.key(0))
        s = j.step(s0, TABLE_FOLD)
        assert float(s.metrics["collided"]) == 1.0
        assert float(s.metrics["collisions"]) == 1.0
        np.testing.assert_allclose(np.asarray(s.obs[:6]), TABLE_FOLD, atol=1e-6)  # colliding obs
        np.testing.assert_allclose(np.asarray(s.q), 0.0)  # then back at the reset pose
        np.testing.assert_allclose(np.asarray(s.qvel), 0.0)
        d = float(s.metrics["distance"])
        free = float(
            mara_mjx.envs.rewards.reward(
                d, 0.0, False, j.env.default_params.reward, orientation=False, collision=False
            )
        )
        assert (float(s.reward) < free - 2.0) == penalised
        # the episode goes on
        assert not bool(s.terminated) and not bool(s.truncated)
        s = j.step(s, SPEC_REACH)
        assert float(s.metrics["collided"]) == 0.0 and float(s.metrics["collisions"]) == 1.0


def test_actions_are_clipped_and_nonfinite_replaced(mara):
    s0 = mara.step(mara.reset(jax.random.key(0)), SPEC_REACH)
    s = mara.step(s0, jnp.array([10.0, -10.0, jnp.nan, jnp.inf, 0.1, -jnp.inf]))
    q = np.asarray(s.obs[:6])  # the pose reached (it may collide and be reset after)
    assert q[0] == pytest.approx(3.1416) and q[1] == pytest.approx(-2.35)
    np.testing.assert_allclose(q[[2, 3, 5]], np.asarray(SPEC_REACH)[[2, 3, 5]], atol=1e-6)
    assert float(s.metrics["nonfinite_actions"]) == 3.0
    assert np.all(np.isfinite(np.asarray(s.obs)))


def test_vmap_step_equals_per_env_step(mara):
    keys = jax.random.split(jax.random.key(0), 3)
    states = jax.vmap(mara.env.reset)(keys)
    actions = jax.random.uniform(jax.random.key(1), (3, 6), minval=-1.0, maxval=1.0)
    actions = actions.at[1].set(TABLE_FOLD)  # one colliding env in the batch
    batched = mara.vstep(states, actions)
    for i in range(3):
        single = mara.step(jax.tree.map(lambda x, i=i: x[i], states), actions[i])
        for a, b in zip(jax.tree.leaves(single), jax.tree.leaves(batched), strict=True):
            if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
                continue
            np.testing.assert_allclose(np.asarray(a), np.asarray(b[i]), rtol=1e-5, atol=1e-6)


def test_params_sweep_does_not_recompile(mara):
    """A new target or new reward hyperparameters go through the same compiled step (the
    retrace guard on mara.step raises if they do not)."""
    from conftest import max_traces

    env = mara.env
    reset = jax.jit(max_traces(env.reset, n=1))
    p = env.make_params(target_pos=(0.3, 0.2, 1.0), alpha=4.0)
    s = mara.step(reset(jax.random.key(0), p), jnp.zeros(6))
    target = np.array([0.3, 0.2, 1.0])
    np.testing.assert_allclose(np.asarray(s.obs[6:9]), TCP_AT_ZERO - target, atol=1e-5)
    s2 = mara.step(reset(jax.random.key(0), env.default_params), jnp.zeros(6))
    assert float(s.reward) != float(s2.reward)


def test_truncation_at_horizon():
    j = jitted("MARA", max_episode_steps=3)
    s = j.reset(jax.random.key(0))
    flags = []
    for _ in range(3):
        s = j.step(s, SPEC_REACH)
        flags.append(bool(s.truncated))
    assert flags == [False, False, True]
    assert not bool(s.terminated)
    assert float(s.metrics["episode_length"]) == 3.0


@pytest.mark.parametrize(
    "name, overrides, match",
    [
        ("MARAX", {}, "registered envs are .*MARACollisionOrient"),
        ("MARA", {"velocity": 3.0}, r"velocity=3.0 .*\(0, 1.57\]"),
        ("MARA", {"driver": "fast"}, r"driver='fast' .*\('train', 'real'\)"),
        ("MARA", {"target_pos": (np.nan, 0.0, 1.0)}, "target_pos=.* must be finite"),
        ("MARA", {"target_pos": (0.1, 0.2)}, r"shape \(3,\)"),
        ("MARA", {"speed": 1.0}, r"unknown env option\(s\) \['speed'\]; valid options"),
        ("MARA", {"target_pos": (2.0, 0.0, 1.0)}, "outside the arm's workspace"),
        ("MARA", {"max_episode_steps": 0}, "max_episode_steps"),
        ("MARA", {"control_dt": 0.0}, "control_dt"),
        ("MARA", {"driver": "real", "control_dt": 0.012}, "multiple of the physics timestep"),
        ("MARA", {"done": float("inf")}, "reward.done"),
        ("MARA", {"target_quat": (0, 0, 0, 0)}, "non-zero quaternion"),
    ],
)
def test_bad_input_errors(name, overrides, match):
    with pytest.raises(ValueError, match=match):
        mara_mjx.make(name, **overrides)


def test_wrong_action_shape(mara):
    s = mara.reset(jax.random.key(0))
    with pytest.raises(ValueError, match=r"action must have shape \(6,\)"):
        mara.env.step(s, jnp.zeros(7))


def test_register_own_variant():
    from mara_mjx.envs.mara import TASKS, MaraEnv, default_config

    def factory(**kw):
        return MaraEnv(
            TASKS["MARA"], default_config(TASKS["MARA"]).replace(max_episode_steps=7, **kw)
        )

    mara_mjx.register("MARAShort", factory, overwrite=True)
    env = mara_mjx.make("MARAShort")
    assert env.max_episode_steps == 7 and "MARAShort" in mara_mjx.registered()
    with pytest.raises(ValueError, match="already registered"):
        mara_mjx.register("MARAShort", factory)


def test_target_override_is_used():
    env = mara_mjx.make("MARA", target_pos=(0.3, 0.2, 1.0))
    np.testing.assert_allclose(np.asarray(env.default_params.target_pos), [0.3, 0.2, 1.0])
    assert env.config.target_pos != DEFAULT_TARGET_POS


# ------------------------------------- unchanged since the random-target tasks came
@pytest.fixture(scope="module")
def as_users_compile(tmp_path_factory) -> dict[str, np.ndarray]:
    """tests/data/fixed_target_golden.py's rollouts of the current code, in a process
    with XLA's default optimisation (not the suite's FAST_COMPILE_FLAGS, conftest.py)."""
    out = tmp_path_factory.mktemp("golden") / "now.npz"
    flags = os.environ.get("XLA_FLAGS", "").replace(FAST_COMPILE_FLAGS, "").strip()
    proc = subprocess.run(
        [sys.executable, str(DATA / "fixed_target_golden.py"), str(out)],
        cwd=DATA.parents[1],
        env={**os.environ, "XLA_FLAGS": flags, "PYTHONPATH": str(DATA.parents[1])},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    return dict(np.load(out))


@pytest.mark.parametrize("name", TASK_NAMES)
def test_fixed_target_tasks_are_unchanged_bit_for_bit(name, as_users_compile):
    """Reset and 4 steps (one colliding) of each fixed task give the arrays recorded on
    commit c6cf3b4, before the random-target tasks (tests/data/fixed_target_golden.py)."""
    golden = np.load(DATA / "fixed_target_golden.npz")
    assert set(mara_mjx.make(name).metric_keys) == set(METRIC_KEYS)  # no new metrics either
    same_platform = str(golden["jax_version"]) == str(as_users_compile["jax_version"]) and str(
        golden["backend"]
    ) == str(as_users_compile["backend"])
    keys = [k.split("/", 1)[1] for k in golden.files if k.startswith(f"{name}/")]
    assert keys and {f"{name}/{k}" for k in keys} <= set(as_users_compile)
    for key in keys:
        value, expected = as_users_compile[f"{name}/{key}"], golden[f"{name}/{key}"]
        if same_platform:
            np.testing.assert_array_equal(value, expected, err_msg=f"{name} {key}")
        else:  # another XLA may round the last bit differently
            np.testing.assert_allclose(value, expected, rtol=1e-5, atol=1e-6, err_msg=key)
    # the rollout is not trivial: a collision, and the arm near the target at step 1
    assert golden[f"{name}/collided"][3] == 1.0 and golden[f"{name}/distance"][1] < 0.01


def test_train_driver_never_loads_mjx_and_mjx_builds_inside_a_trace():
    """The default (lean) train driver runs without importing mujoco.mjx (its import and
    the device models were ~2 s of the train CLI's start-up); the MJX paths still build
    their models on first use, also when that first use is inside a jit trace (concrete
    arrays, no leaked tracers: a reference check and a kinematics call in a later trace,
    which a leaked tracer fails; jitted: op by op it took 11 s), and the TCP they give is
    C MuJoCo's."""
    code = """
import sys, jax, jax.numpy as jnp, mara_mjx
env = mara_mjx.make("MARACollisionOrient")
s = jax.jit(env.reset)(jax.random.key(0))
s = jax.jit(env.step)(s, jnp.zeros(6))
assert "mujoco.mjx" not in sys.modules, "lean train driver imported mujoco.mjx"
arm = mara_mjx.make("MARA", kinematics="mjx").arm
inside = jax.jit(lambda q: arm.pose(q).tcp_pos)(jnp.zeros(6))  # first use under a trace
outside = jax.jit(lambda q: arm.pose(q).tcp_pos)(jnp.zeros(6))  # a later trace
assert "mujoco.mjx" in sys.modules
assert isinstance(arm.mjx_model.body_mass, jax.Array), type(arm.mjx_model.body_mass)
c_mujoco = arm.mj_data(jnp.zeros(6)).site_xpos[arm.tcp_site]
print(float(jnp.max(jnp.abs(inside - c_mujoco))))
print(float(jnp.max(jnp.abs(inside - outside))))
"""
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": FAST_COMPILE_FLAGS}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    to_c_mujoco, to_inside = map(float, out.stdout.strip().splitlines()[-2:])
    assert to_inside < 1e-6 and to_c_mujoco < 1e-5, (to_inside, to_c_mujoco)
