"""The ONNX graph of a deployed policy with IK rules, traced from the JAX policy itself
(jax2onnx; the optional `[export]` extra, export time only: a robot needs onnxruntime alone).

    pip install 'mara_mjx[export]'
    python -m mara_mjx.export runs/MARACollisionOrient-.../ policy.onnx

    from mara_mjx.deploy import onnx_graph
    model = onnx_graph.build_model(policy, lower, upper, meta)   # checked, or OnnxGraphError
    onnx_graph.save(model, "policy.onnx")

    import onnxruntime as ort
    session = ort.InferenceSession("policy.onnx")
    targets, = session.run(["action_clipped"], {"obs": obs[None].astype(np.float32)})

The graph is a trace of `deployed_step`: `Policy.__call__` (mara_mjx/ppo/policy.py, the
function evaluation, play and the adapters run: the quaternion sign, the normaliser, the
actor MLP, the IK step of mara_mjx/envs/task_space.py with its gates, the long way round,
orient-first's rules, the guard and the finish, each as the checkpoint's PolicyConfig
says) and the env's clip to the joint limits. One source of truth: no rule is restated
here. The hand-written graph of mara_mjx/deploy/onnx_policy.py stays for the joint-space
policies (an MLP of ~20 nodes, exact, and it needs only the `onnx` package).

    input  obs             (N, obs_size) float32, the raw observation (env.observation_layout)
    output action          (N, 6) rad, the policy's joint targets
    output action_clipped  (N, 6) rad, clipped to the joint limits, as the env does

`batch`: None, any N (a symbolic dimension); an int, that N only (batch 1: about half the
nodes and half the latency of a robot's step). The metadata (`meta`: the export's layout,
units, joint names and limits, control period, recipe) is stored as metadata_props
["mara_mjx"] (JSON), as onnx_policy's is.

The trace runs on the CPU: `task_space.dls_step` then takes the written-out Cholesky
(envs/linalg.py), which lowers to ONNX, where the GPU's LU does not (a GPU-trained policy
solves the same symmetric positive-definite system; the two differ at float32's floor).

Before a model is returned it is checked (`self_check`): onnx.checker's full check, then
onnxruntime against the jitted JAX step on `check_observations` (arm poses with
sigma_min(J) >= 0.05, targets from a millimetre to half a radian of joint motion away):
max |diff| <= `tolerance` (1e-4 rad) plus twice the jitted step's own spread when its
inputs are rounded differently (`own_spread`: ~1e-6 rad at most observations, a few 1e-4
at a few), against the jitted step, or else against the eager one (JAX's own jit and
eager differ by ~1e-4 at float32 there); for a policy with a plan
(PolicyConfig.plan_steps K), 95% of the observations within 1e-4 x (1 + K / 4) and each
within that plus the jitted step's own spread when its inputs are rounded differently
(`own_spread`: K imagined steps are chaotic at a few observations). Else OnnxGraphError
and nothing is written. A
converter bug must not reach a robot silently (jax2onnx 0.17.1 once lowered a batched
gather to a wrong GatherND). Near a singular posture (sigma_min(J) at the 0.02 damping)
any float32 evaluation of the IK step is only good to ~3e-4, JAX's own jit against eager
included (benchmarks/archive/jax2onnx/FINDINGS.md).
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

OPSET = 17
TOLERANCE = 1e-4
"""rad: onnxruntime against the JAX step on the check observations."""
ROUNDING_DRAWS = 32
"""The check: how many times each check observation is re-rounded to measure the jitted
step's own sensitivity (`own_spread`)."""
SPREAD_MARGIN = 2.0
"""The check: the graph, one more float32 evaluation, may differ from the
jit by this many times the largest of the draws' moves (a maximum over 32 draws samples
the range of a chaotic observation's outputs, it does not bound it)."""
MIN_SINGULAR = 0.05
"""The check observations' arm poses: sigma_min of the TCP Jacobian at least this."""
INSTALL = "pip install 'mara_mjx[export]' (or pip install jax2onnx==0.17.1)"


class OnnxGraphError(ValueError):
    """The graph cannot be built, or does not compute what the JAX policy computes."""


def deployed_step(policy: Any, lower: Any, upper: Any) -> Callable[[Any], tuple[Any, Any]]:
    """obs (..., obs_size) -> (policy(obs), clip(policy(obs), lower, upper)), (..., 6) rad:
    the deterministic step a deployed policy takes, as evaluation takes it (the env clips)."""
    import jax.numpy as jnp

    lower, upper = np.asarray(lower, np.float32), np.asarray(upper, np.float32)

    def step(obs: Any) -> tuple[Any, Any]:
        action = policy(obs)
        return action, jnp.clip(action, lower, upper)

    return step


def build_model(
    policy: Any,
    lower: Any,
    upper: Any,
    meta: dict[str, Any],
    batch: int | None = None,
    tolerance: float = TOLERANCE,
) -> Any:
    """The checked onnx.ModelProto of `deployed_step(policy, lower, upper)` (module
    docstring). OnnxGraphError without jax2onnx, off the CPU backend, or when the check
    fails."""
    import jax

    try:
        from jax2onnx import to_onnx
    except ImportError as e:
        raise OnnxGraphError(
            f"exporting a policy with IK rules to .onnx needs jax2onnx: {INSTALL}"
        ) from e
    if jax.default_backend() != "cpu":
        raise OnnxGraphError(
            "the ONNX graph is traced on the CPU (the IK step's written-out solve); run the "
            f"export with JAX_PLATFORMS=cpu (the default backend is {jax.default_backend()!r})"
        )
    from onnx import helper

    size = int(meta["observation_size"])
    step = deployed_step(policy, lower, upper)
    with _fast_output_binding():
        model = to_onnx(
            step,
            [(batch or "N", size)],
            model_name=f"mara_mjx_{meta['env_name']}_policy",
            opset=OPSET,
            input_names=["obs"],
            output_names=["action", "action_clipped"],
        )
    model.producer_name = "mara_mjx (jax2onnx)"
    model.doc_string = (
        f"Deterministic policy for {meta['env_name']}: obs (N, {size}) -> action, "
        "action_clipped (N, 6) rad (absolute joint targets motor1..motor6), with its IK rules."
    )
    obs = check_observations(meta, 128 if batch is None else batch * max(1, 128 // batch))
    want = [np.asarray(x) for x in jax.jit(step)(obs)]
    steps = getattr(policy.config.policy, "plan_steps", 0)
    if steps and getattr(policy.config.policy, "plan_starts", 0):  # the longest imagination
        from mara_mjx.ppo.parametrisation import PLAN_START_STEPS

        steps = max(steps, PLAN_START_STEPS)
    spread = own_spread(step, obs, want)
    if steps:
        # K imagined steps amplify float32's rounding where the plan is sensitive to its
        # start: on a trained random-target policy at K = 16, one or two of 128 check
        # observations move the jitted step by 2e-2 to 6e-2 rad when their inputs are
        # rounded differently by an ulp, ~2e-6 on the rest (benchmarks/NOTES.md sections
        # 42 and 44). No float32 evaluation, the graph's included, can be held closer there
        # than that. So: 95% of the observations within the tolerance x (1 + K / 4), and
        # every one within that bound plus SPREAD_MARGIN x the jitted step's own spread
        bound = tolerance * (1 + steps / 4)
        allowed = bound + SPREAD_MARGIN * spread
        diff = self_check(model, obs, want, batch, allowed, quantile=(0.95, bound))
        reference = (
            f"jit; plan_steps: 95% within {bound:.0e}, each within it plus {SPREAD_MARGIN:g}x "
            f"the jit's own spread under input rounding (largest {spread.max():.1e})"
        )
    else:
        # each observation within the tolerance plus the jit's own spread: where 2-4 ulps
        # of input rounding move the jitted step by more than 1e-4 (measured: 2.8e-4 to
        # 5.6e-4 at 3 of 128 check observations of a random orient-first policy on an AMD
        # EPYC CPU, ~1e-6 at the rest; benchmarks/NOTES.md section 71), no float32
        # evaluation, the graph's included, can be held to 1e-4 (32 more jitted calls)
        allowed = tolerance + SPREAD_MARGIN * spread
        diff, reference = _check_against_jit_or_eager(model, obs, want, batch, allowed, step)
        reference += (
            f"; each within {tolerance:.0e} plus {SPREAD_MARGIN:g}x the jit's own spread under "
            f"input rounding (largest {spread.max():.1e})"
        )
    meta = {**meta, "self_check": {
        "observations": len(obs), "max_abs_diff": diff, "reference": reference}}  # fmt: skip
    helper.set_model_props(model, {"mara_mjx": json.dumps(meta)})
    return model


def own_spread(
    step: Callable[[Any], tuple[Any, Any]],
    obs: np.ndarray,
    want: list[np.ndarray],
    draws: int = ROUNDING_DRAWS,
    seed: int = 0,
) -> np.ndarray:
    """(M,) rad: per observation of `obs`, the most the jitted `step`'s outputs moved from
    `want` (its outputs on `obs`) when every input was perturbed by a relative 2**-22 (2-4
    float32 ulps), over `draws` draws: a sample of how far two float32 evaluations of the
    step can disagree there (~2e-6 rad on a smooth observation; up to the size of the
    output's range on a chaotic one)."""
    import jax

    jitted, rng, spread = jax.jit(step), np.random.default_rng(seed), np.zeros(len(obs))
    for _ in range(draws):
        noisy = (obs * (1 + 2.0**-22 * rng.uniform(-1, 1, obs.shape))).astype(np.float32)
        got = [np.asarray(x) for x in jitted(noisy)]
        moved = np.max([np.abs(g - w).max(-1) for g, w in zip(got, want, strict=True)], 0)
        spread = np.maximum(spread, moved)
    return spread


def _check_against_jit_or_eager(
    model: Any,
    obs: np.ndarray,
    want: list[np.ndarray],
    batch: int | None,
    tolerance: float | np.ndarray,
    step: Callable[[Any], tuple[Any, Any]],
) -> tuple[float, str]:
    """(difference, reference) of `self_check` against the jitted step `want`, or, where
    that fails, against the eager step; the jit's OnnxGraphError where both fail."""
    import jax

    try:
        return self_check(model, obs, want, batch, tolerance), "jit"
    except OnnxGraphError as against_jit:
        # JAX's own two float32 evaluations of the step differ by about 1e-4 rad (measured
        # 1.24e-4, jit against eager, on a random orient-first policy whose graph was 1.14e-4
        # from the jit and 4.6e-5 from the eager step; benchmarks/NOTES.md section 38): the
        # graph passes if it is within the tolerance of either
        import jax.numpy as jnp

        with jax.disable_jit():
            eager = [np.asarray(x) for x in step(jnp.asarray(obs))]
        try:
            return self_check(model, obs, eager, batch, tolerance), "eager"
        except OnnxGraphError:
            raise against_jit from None


def save(model: Any, file: Any) -> None:
    """Write `model` to `file` (a path or a binary file object)."""
    import onnx

    onnx.save(model, file)


def self_check(
    model: Any,
    obs: np.ndarray,
    want: list[np.ndarray],
    batch: int | None,
    tolerance: float | np.ndarray = TOLERANCE,
    quantile: tuple[float, float] | None = None,
) -> float:
    """onnx.checker's full check, then max |onnxruntime - want| over both outputs on `obs`
    (M, obs_size), `want` the JAX step's (action, action_clipped), the graph run in chunks
    of `batch` (None: all at once). OnnxGraphError when the
    checker refuses the model, onnxruntime cannot run it, or an observation's difference
    exceeds `tolerance` (rad; one for all, or (M,) one per observation; with `quantile`
    (f, t): also where fewer than the fraction f of the observations are within t); else
    the largest difference (rad)."""
    import onnx
    import onnxruntime as ort

    try:
        onnx.checker.check_model(model, full_check=True)
        options = ort.SessionOptions()
        options.log_severity_level = 3
        session = ort.InferenceSession(
            model.SerializeToString(), options, providers=["CPUExecutionProvider"]
        )
        chunk = batch or len(obs)
        got = [
            np.concatenate(x)
            for x in zip(
                *(
                    session.run(None, {"obs": obs[i : i + chunk]})
                    for i in range(0, len(obs), chunk)
                ),
                strict=True,
            )
        ]
    except Exception as e:  # the checker's and onnxruntime's own error types
        raise OnnxGraphError(f"the traced graph is not a valid ONNX model: {e}") from e
    rows = np.max([np.abs(g - w).max(-1) for g, w in zip(got, want, strict=True)], 0)
    diff = float(rows.max())
    share_ok = quantile is None or np.mean(rows <= quantile[1]) >= quantile[0]
    allowed = np.broadcast_to(np.asarray(tolerance, np.float64), rows.shape)
    over = ~(rows <= allowed)  # (a NaN row is over)
    if over.any() or not share_ok:
        worst = int(np.argmax(rows - allowed))
        raise OnnxGraphError(
            f"the traced graph differs from the JAX policy by {diff:.2e} rad on "
            f"{len(obs)} check observations ("
            + (f"{int(over.sum())} beyond their tolerance, the worst by {rows[worst]:.2e} "
               f"where {allowed[worst]:.2e} is allowed" if over.any() else
               "each within its tolerance")
            + ("" if quantile is None else
               f"; {100 * np.mean(rows <= quantile[1]):.0f}% within {quantile[1]:.0e}, "
               f"{100 * quantile[0]:.0f}% needed")
            + "): not written"
        )  # fmt: skip
    return diff


def check_observations(meta: dict[str, Any], n: int = 128, seed: int = 0) -> np.ndarray:
    """(n, obs_size) float32 observations as the env builds them (meta's observation_layout:
    q, e, quat_err, v) from the nominal arm: q inside the joint box where sigma_min(J) >=
    MIN_SINGULAR, the target the TCP pose of q plus a joint move of 1 mm-scale to 0.5 rad,
    v = J_pos(q) qdot for a small qdot."""
    import jax
    import jax.numpy as jnp

    from mara_mjx.envs.geometry import quat_canonical, quat_conj, quat_mul
    from mara_mjx.envs.task_space import nominal_chain

    chain = nominal_chain()
    lower = np.asarray(meta["action"]["lower"], np.float64)
    upper = np.asarray(meta["action"]["upper"], np.float64)
    rng = np.random.default_rng(seed)
    q = rng.uniform(0.8 * lower, 0.8 * upper, (8 * n, 6)).astype(np.float32)
    jac = np.asarray(jax.jit(jax.vmap(chain.jacobian))(q), np.float64)
    q = q[np.linalg.svd(jac, compute_uv=False)[:, -1] >= MIN_SINGULAR][:n]
    if len(q) < n:
        raise OnnxGraphError("too few well-conditioned arm poses for the self-check")
    scale = rng.choice([0.003, 0.03, 0.1, 0.5], (n, 1)) * rng.uniform(0.5, 1.5, (n, 1))
    target_q = np.clip(q + scale * rng.normal(size=(n, 6)), lower, upper).astype(np.float32)
    qdot = rng.normal(0.0, 0.1, (n, 6)).astype(np.float32)

    @jax.jit
    def parts(q, target_q, qdot):
        pos, quat = jax.vmap(chain.tcp)(q)
        target_pos, target_quat = jax.vmap(chain.tcp)(target_q)
        quat_err = quat_mul(quat_canonical(quat), quat_conj(target_quat))
        v = jnp.einsum("nij,nj->ni", jax.vmap(chain.jacobian)(q)[:, :3], qdot)
        return {"q": q, "e": pos - target_pos, "quat_err": quat_err, "v": v}

    values = parts(q, target_q, qdot)
    obs = np.zeros((n, int(meta["observation_size"])), np.float32)
    for part in meta["observation_layout"]:
        if part["name"] not in values:
            raise OnnxGraphError(f"no check observations for the part {part['name']!r}")
        obs[:, part["start"] : part["stop"]] = np.asarray(values[part["name"]])
    return obs


@contextlib.contextmanager
def _fast_output_binding() -> Iterator[None]:
    """jax2onnx 0.17.1's `output_binding._value_is_graph_connected` scans the whole graph
    for every equation (conversion O(nodes^2): ~100 s for an orient-first policy on a
    2-core CPU); this asks the value's producer instead (seconds). The self-check catches
    any error. Upstream material; a no-op where jax2onnx lacks the function."""
    try:
        from jax2onnx.converter import output_binding as ob
    except ImportError:
        yield
        return
    original = getattr(ob, "_value_is_graph_connected", None)
    if original is None or not hasattr(ob, "_value_matches_reference"):
        yield
        return

    def connected(ctx: Any, value: Any) -> bool:
        graph = getattr(ctx.builder, "graph", None)
        if graph is None:
            return original(ctx, value)
        producer = value.producer()
        if producer is not None and producer.graph is graph:
            return True
        if value.name and value.name in graph.initializers:
            return True
        return any(ob._value_matches_reference(x, value) for x in ctx.builder.inputs) or (
            producer is None and original(ctx, value)
        )

    ob._value_is_graph_connected = connected
    try:
        yield
    finally:
        ob._value_is_graph_connected = original
