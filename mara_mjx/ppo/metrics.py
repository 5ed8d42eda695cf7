"""What the trainer reports per update: means over the rollout's steps
(`rollout_metrics`), the deterministic probe step's accuracy (`probe_metric_summary`)
and the reach probe of the saved policy from the reset (`reach_probe`, `reach_row`:
CurriculumConfig.probe_reach_steps), the columns of progress.csv (`mara_mjx.ppo.logger`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp


def rollout_metrics(traj: Any, done: jax.Array) -> dict[str, jax.Array]:
    """Means over the rollout's (T, N) steps. Env metrics are used where the env reports
    them: distance / position_error (m -> mm), orientation_error (rad -> deg), collided,
    nonfinite_actions."""
    m = traj.metrics
    episodes = jnp.sum(done)
    out = {
        "reward_mean": jnp.mean(traj.reward),
        "episodes": episodes.astype(jnp.float32),
        # Mean return of the episodes that ended in this rollout; NaN if none did.
        "episode_return": jnp.where(
            episodes > 0, jnp.sum(traj.episode_return) / jnp.maximum(episodes, 1), jnp.nan
        ),
        "terminations": jnp.sum(traj.terminated).astype(jnp.float32),
    }
    if "distance" in m:
        out["distance_mm"] = 1000.0 * jnp.mean(m["distance"])
    if "position_error" in m:
        out["position_error_mm"] = 1000.0 * jnp.mean(m["position_error"], axis=(0, 1))
    if "orientation_error" in m:
        out["orientation_error_deg"] = jnp.degrees(jnp.mean(m["orientation_error"], axis=(0, 1)))
    if "collided" in m:
        out["collision_rate"] = jnp.mean(m["collided"])
    if "nonfinite_actions" in m:
        out["nonfinite_actions"] = jnp.sum(m["nonfinite_actions"])
    return out


def probe_metric_summary(m: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """Accuracy of the deterministic policy: one step with the Gaussian mean from every
    env's state at the end of the rollout. `det_error_mm` is the mean over envs and axes of
    |e| after that step, the "mean per-axis error" of the time-to-accuracy records."""
    out = {}
    if "position_error" in m:
        per_axis = 1000.0 * jnp.mean(m["position_error"], axis=0)
        out["det_position_error_mm"] = per_axis
        out["det_error_mm"] = jnp.mean(per_axis)
    if "distance" in m:
        out["det_distance_mm"] = 1000.0 * jnp.mean(m["distance"])
    if "orientation_error" in m:
        out["det_orientation_error_deg"] = jnp.degrees(jnp.mean(m["orientation_error"], axis=0))
    return out


def num_parameters(params: Any) -> int:
    return sum(math.prod(x.shape) for x in jax.tree.leaves(params))


PROBE_REACH_EPISODES = 4
"""CurriculumConfig.probe_reach_steps: episodes of the probe from the reset."""
PROBE_REACH_NOISE = 0.02
"""CurriculumConfig.probe_reach_steps: the probe's reset noise (rad), the paper evaluation's."""


def reach_probe(env: Any, policy: Callable[[jax.Array], tuple], steps: int) -> jax.Array:
    """CurriculumConfig.probe_reach_steps: mean per-axis |e| (mm) of the saved
    (deterministic) policy (`policy(obs)` -> (mean, ...)) after `steps` steps from the
    env's reset, PROBE_REACH_EPISODES episodes with the paper's evaluation noise (fixed
    keys: the same episodes every call)."""
    noisy = hasattr(getattr(env, "default_params", None), "reset_noise")
    env_params = env.make_params(reset_noise=PROBE_REACH_NOISE) if noisy else None
    keys = jax.random.split(jax.random.key(0), PROBE_REACH_EPISODES)
    env_state = jax.vmap(env.reset, in_axes=(0, None))(keys, env_params)

    def body(env_state, _):
        return jax.vmap(env.step)(env_state, policy(env_state.obs)[0]), None

    env_state, _ = jax.lax.scan(body, env_state, None, length=steps)
    return 1000.0 * jnp.mean(env_state.metrics["position_error"])


def reach_row(reach: Any, num_updates: Any, rows: int) -> jax.Array:
    """The `reach_error_mm` column of one call's `rows` metric rows: `reach` on the last
    valid row (of `num_updates`), NaN on the others (float32, in or out of jit)."""
    last = jnp.clip(num_updates, 1, rows) - 1
    return jnp.full(rows, jnp.nan, jnp.float32).at[last].set(reach)
