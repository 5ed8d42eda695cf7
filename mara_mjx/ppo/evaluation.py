"""The paper's accuracy evaluation (spec section 7) of a deterministic policy.

`EvalConfig.episodes` episodes run in parallel (a vmap of the env, no auto-reset), each
from the reset pose perturbed by a uniform noise of half-width `EvalConfig.noise` rad in
every joint (the env's `reset_noise` param) so that the episodes differ; episode i uses
key `split(key(seed), episodes)[i]`. The policy is the Gaussian mean. An episode stops at
the first step where every axis of |e| is within `tolerance_mm` (the original run
scripts' stop condition) or at the horizon (`max_episode_steps`); its final position
error (mm, per axis) and orientation error (deg, per axis: |roll|, |pitch|, |yaw| of
quat_err) are those of that step. The table reports mean +- std (numpy's population
std) over the episodes, beside the paper's numbers.

The episode protocol (`episode_plan`, `reached_tolerance`, `episode_record`) is shared
with `python -m mara_mjx.play`, which plays the same episodes one at a time on the host.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.deploy.numpy_policy import committed
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.parametrisation import check_plan_period, plan_overrides
from mara_mjx.ppo.policy import Policy, limit_step

# Spec section 7: mean and std over 10 runs, per axis; mm and degrees.
PAPER_RESULTS: dict[str, dict[str, tuple[tuple[float, float], ...]]] = {
    "MARA": {"position_mm": ((5.74, 6.73), (6.78, 5.27), (6.38, 4.72))},
    "MARACollision": {"position_mm": ((5.68, 7.34), (4.53, 6.61), (3.13, 7.85))},
    "MARAOrient": {
        "position_mm": ((3.03, 1.89), (8.95, 2.54), (5.85, 4.38)),
        "orientation_deg": ((0.71, 0.29), (1.61, 1.25), (7.52, 2.48)),
    },
    "MARACollisionOrient": {
        "position_mm": ((7.43, 3.07), (4.69, 2.37), (5.18, 3.44)),
        "orientation_deg": ((2.62, 3.80), (4.06, 2.20), (6.43, 6.81)),
    },
}


@dataclasses.dataclass(frozen=True)
class EvalResult:
    """Per-episode numbers at each episode's stop step, (E, ...) numpy arrays."""

    position_error_mm: np.ndarray  # (E, 3) |e_x|, |e_y|, |e_z|
    orientation_error_deg: np.ndarray  # (E, 3) |roll|, |pitch|, |yaw| of quat_err
    distance_mm: np.ndarray  # (E,) RMS of e
    steps: np.ndarray  # (E,) steps taken until the stop
    reached: np.ndarray  # (E,) bool, stopped by the tolerance (not the horizon)
    collisions: np.ndarray  # (E,) collisions until the stop
    episode_return: np.ndarray  # (E,) sum of rewards until the stop

    def episodes(self) -> list[dict[str, Any]]:
        return [
            {
                "episode": i,
                "position_error_mm": self.position_error_mm[i].tolist(),
                "orientation_error_deg": self.orientation_error_deg[i].tolist(),
                "distance_mm": float(self.distance_mm[i]),
                "steps": int(self.steps[i]),
                "reached_tolerance": bool(self.reached[i]),
                "collisions": int(self.collisions[i]),
                "return": float(self.episode_return[i]),
            }
            for i in range(len(self.steps))
        ]

    def summary(self) -> dict[str, Any]:
        def stat(x: np.ndarray) -> dict[str, Any]:
            x = np.asarray(x, np.float64)
            return {"mean": np.mean(x, 0).tolist(), "std": np.std(x, 0).tolist()}

        return {
            "position_error_mm": stat(self.position_error_mm),
            "orientation_error_deg": stat(self.orientation_error_deg),
            "distance_mm": stat(self.distance_mm),
            "mean_axis_error_mm": float(np.mean(self.position_error_mm)),
            "reached_tolerance": int(np.sum(self.reached)),
            "episodes": len(self.steps),
            "steps": stat(self.steps),
            "collisions": int(np.sum(self.collisions)),
        }


def episode_plan(env: Any, config: EvalConfig) -> tuple[Any, jax.Array]:
    """(params, keys): the env params of every episode (the reset noise) and the
    (episodes,) keys, episode i from key i."""
    params = env.make_params(reset_noise=config.noise)
    return params, jax.random.split(jax.random.key(config.seed), config.episodes)


def reached_tolerance(metrics: dict[str, jax.Array], config: EvalConfig) -> jax.Array:
    """The stop rule: every axis of |e| within tolerance_mm (never when it is 0)."""
    error = metrics["position_error"]
    if config.tolerance_mm <= 0:
        return jnp.zeros(jnp.shape(error)[:-1], bool)
    return jnp.all(error <= config.tolerance_mm / 1000.0, axis=-1)


def episode_record(state: Any, reached: jax.Array) -> dict[str, jax.Array]:
    """EvalResult's fields of (a batch of) states at their stop step."""
    m = state.metrics
    return {
        "position_error_mm": 1000.0 * m["position_error"],
        "orientation_error_deg": jnp.degrees(m["orientation_error"]),
        "distance_mm": 1000.0 * m["distance"],
        "steps": state.step,
        "reached": reached,
        "collisions": m["collisions"],
        "episode_return": m["episode_return"],
    }


def make_evaluate(
    env: Any, config: EvalConfig, params: Any = None
) -> Callable[[Policy], dict[str, jax.Array]]:
    """A jitted fn(policy) -> per-episode arrays (see EvalResult) for this env and config.
    The policy is an argument (a pytree), so one compile serves every checkpoint.
    `params`: None (`episode_plan`'s: the reset noise for every episode) or params with a
    leading (episodes,) axis, one per episode (e.g. each its own target)."""
    per_episode = params is not None
    plan_params, keys = episode_plan(env, config)
    if params is None:
        params = plan_params
    horizon = env.max_episode_steps
    reset = jax.vmap(env.reset, in_axes=(0, 0 if per_episode else None))
    step = jax.vmap(env.step)

    if config.rate_limit:
        driver = getattr(env.config, "driver", "train")
        if driver != "real":
            raise ValueError(
                f"rate_limit=true limits the policy's steps to the real driver's servo speed, "
                f"but the env's driver is {driver!r}; use driver='real' or rate_limit=false"
            )
        # the servos' travel per control step: velocity (per episode where params carry
        # one each) x the physics substeps of one step
        step_s = env.n_substeps * env.arm.timestep
        velocity = jnp.asarray(params.velocity, jnp.float32)
        max_step = (velocity * step_s)[..., None] if velocity.ndim else velocity * step_s

    def evaluate(policy: Policy) -> dict[str, jax.Array]:
        policy = deployed_policy(policy, config, env)
        commit = deployed_commit(policy, config)
        # the joint limits the env clips to (a MARA env's; only where a rule needs them)
        bounds = (
            (np.asarray(env.joint_lower, np.float32), np.asarray(env.joint_upper, np.float32))
            if commit > 0.0 or config.rate_limit
            else None
        )
        state = reset(keys, params)

        def act(obs, held, q_previous):
            """The targets sent (rate-limited when asked) and the targets held."""
            action, q = held_action(policy, obs, held, q_previous, commit, bounds)
            sent = limit_step(action, q, max_step, bounds) if config.rate_limit else action
            return sent, action, q

        def running(carry) -> jax.Array:
            _, active, _, t, _ = carry
            return (t < horizon) & jnp.any(active)

        def body(carry):
            state, active, rec, t, (held, q_previous) = carry
            sent, held, q_previous = act(state.obs, held, q_previous)
            state = step(state, sent)
            new = episode_record(state, reached_tolerance(state.metrics, config))
            keep = lambda r, n: jnp.where(  # noqa: E731
                active.reshape(active.shape + (1,) * (n.ndim - 1)), n, r
            )
            rec = jax.tree.map(keep, rec, new)
            active = active & ~new["reached"] & ~state.terminated & ~state.truncated
            return state, active, rec, t + 1, (held, q_previous)

        active = jnp.ones(config.episodes, bool)
        first = episode_record(state, jnp.zeros(config.episodes, bool))
        q0 = state.obs[..., : env.action_size]  # held = q_previous = q: the first choice is free
        init = (state, active, first, jnp.zeros((), jnp.int32), (q0, q0))
        _, _, rec, _, _ = jax.lax.while_loop(running, body, init)
        return rec

    return jax.jit(evaluate)


def held_action(
    policy: Any, obs: jax.Array, held: jax.Array, q_previous: jax.Array, commit: float, bounds
) -> tuple[jax.Array, jax.Array]:
    """(targets, observed joints) of `policy` at `obs` under PolicyConfig.commit_rad's rule
    (`commit` > 0: deploy/numpy_policy.committed with the targets `held` and the joints
    `q_previous` of the last step, `bounds` the joint limits; 0: the policy's own): the
    one deployed step of the evaluation loop and `play`."""
    action = policy(obs)
    q = obs[..., : action.shape[-1]]
    if commit > 0.0:
        action = committed(q, action, held, q_previous, commit, *bounds, xp=jnp)
    return action, q


def deployed_policy(policy: Any, config: EvalConfig, env: Any) -> Any:
    """`policy` as the evaluation loop and `play` run it: EvalConfig's collision guard
    (where >= 0) and plan overrides applied (`with_collision_guard`, `deployed_plan`), the
    plan's control period checked against `env`'s (a checkpoint's Policy; an exported
    file's carries its own rules). Held commands are applied around it (`held_action`)."""
    if config.collision_guard_mm >= 0.0:
        policy = with_collision_guard(policy, config.collision_guard_mm)
    policy = deployed_plan(policy, config)
    if hasattr(policy, "config"):  # a checkpoint's Policy (an exported file has none)
        check_plan_period(policy.config.policy.plan_steps, env)  # (at trace time)
    return policy


def deployed_plan(policy: Any, config: EvalConfig) -> Any:
    """`policy` with EvalConfig's plan overrides (plan_steps, plan_starts; -1 leaves the
    checkpoint's): plan_steps=0 turns its restarts off too. ValueError for a policy
    without a config (an exported file's) when one is given, or an invalid pair."""
    steps, starts = (None if v == -1 else v for v in (config.plan_steps, config.plan_starts))
    plan = plan_overrides(steps, starts)
    return with_deployed(policy, **plan) if plan else policy


def deployed_commit(policy: Any, config: EvalConfig) -> float:
    """The arrival tolerance (rad; 0: off) of PolicyConfig.commit_rad the evaluation
    applies around `policy`: EvalConfig.commit_rad where >= 0, else the checkpoint
    policy's own (an exported file's comes in EvalConfig: `evaluate` reads its metadata,
    `deploy.in_the_loop.commit_rad`)."""
    if config.commit_rad >= 0.0:
        return float(config.commit_rad)
    return float(
        getattr(getattr(getattr(policy, "config", None), "policy", None), "commit_rad", 0.0)
    )


def with_collision_guard(policy: Any, mm: float) -> Any:
    """`policy` (a checkpoint's Policy) with its deployed collision guard set to `mm`
    (PolicyConfig.collision_guard_mm; 0: off); ValueError for a policy without a config
    (an exported file's, a plain function)."""
    return with_deployed(policy, "collision_guard_mm", float(mm))


def with_deployed(policy: Any, field: str | None = None, value: Any = None, **fields) -> Any:
    """`policy` (a checkpoint's Policy) with the deployed-only PolicyConfig `field` set to
    `value` (collision_guard_mm, plan_steps, plan_starts), or each of `fields` at once;
    ValueError for a policy without a config (an exported file's, a plain function: it
    carries the rules it was exported with)."""
    if field is not None:
        fields[field] = value
    config = getattr(policy, "config", None)
    if config is None or not hasattr(policy, "replace"):
        named = ", ".join(f"{k}={v}" for k, v in fields.items())
        raise ValueError(
            f"{named} sets a checkpoint policy's deployed rule, but this policy has "
            "no config (an exported file carries the rules it was exported with)"
        )
    return policy.replace(config=config.replace(**fields))


def evaluate(
    env: Any, policy: Policy, config: EvalConfig, params: Any = None, fn: Any = None
) -> EvalResult:
    """Run the evaluation (compiles once per env and config); `params` as in
    `make_evaluate`; `fn`: `make_evaluate(env, config, params)` made (and compiled)
    beforehand."""
    fn = make_evaluate(env, config, params) if fn is None else fn
    out = jax.device_get(fn(policy))
    return EvalResult(**{k: np.asarray(v) for k, v in out.items()})


def format_table(task: str, result: EvalResult, orientation: bool, config: EvalConfig) -> str:
    """The accuracy table in the layout of spec section 7, with the paper's row."""
    header = ["task", "x", "y", "z"]
    if orientation:
        header += ["orientation x", "orientation y", "orientation z"]

    def cells(pairs) -> list[str]:
        return [f"{m:.2f} +- {s:.2f}" for m, s in pairs]

    summary = result.summary()
    pos, ori = summary["position_error_mm"], summary["orientation_error_deg"]
    ours = [f"{task} (this policy)", *cells(zip(pos["mean"], pos["std"], strict=True))]
    if orientation:
        ours += cells(zip(ori["mean"], ori["std"], strict=True))
    rows = [ours]
    paper = PAPER_RESULTS.get(task)
    if paper is not None:
        row = [f"{task} (paper)", *cells(paper["position_mm"])]
        if orientation:
            row += cells(paper.get("orientation_deg", ((np.nan, np.nan),) * 3))
        rows.append(row)
    stop = (
        f"stop when every axis of |e| <= {config.tolerance_mm:g} mm or at the horizon"
        if config.tolerance_mm > 0
        else "run to the horizon"
    )
    lines = [
        f"Accuracy of the deterministic policy over {len(result.steps)} episodes "
        f"(reset noise {config.noise:g} rad, {stop}); mean +- std per axis, distance in mm"
        + (", orientation in degrees" if orientation else ""),
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *("| " + " | ".join(r) + " |" for r in rows),
        f"reached the tolerance in {int(result.reached.sum())}/{len(result.steps)} episodes; "
        f"steps {result.steps.mean():.1f} +- {result.steps.std():.1f}; "
        f"collisions {int(result.collisions.sum())}",
    ]
    return "\n".join(lines)
