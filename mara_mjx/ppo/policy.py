"""The policy artefact and its one factory, `make_policy`.

A policy is params + config (+ observation statistics when the run normalised them). The
deterministic policy is the Gaussian mean: absolute joint targets (rad) for the env,
which clips them to the joint limits.

    policy = make_policy("runs/MARA-.../checkpoints/ckpt_00000100.npz")   # or load_policy
    action = policy(obs)                       # (obs_size,) or (N, obs_size) -> (..., 6)
    action = jax.jit(policy)(obs)              # or pass `policy` into a jitted function:
                                               # it is a pytree (params traced, config static)
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mara_mjx.ppo.checkpoint import (
    CheckpointError,
    arrays_to_state,
    find_checkpoint,
    load_checkpoint,
)
from mara_mjx.ppo.config import PPOConfig, TrainConfig, as_train_config
from mara_mjx.ppo.members import member_axis
from mara_mjx.ppo.networks import ActorCritic, RunningStats, forward, make_network


@struct.dataclass
class Policy:
    """Deterministic policy obs -> Gaussian mean. A pytree: pass it through jit/vmap."""

    params: Any
    obs_stats: RunningStats | None
    config: TrainConfig = struct.field(pytree_node=False)
    action_size: int = struct.field(pytree_node=False)

    @property
    def network(self) -> ActorCritic:
        return make_network(self.config, self.action_size)

    def __call__(self, obs: jax.Array) -> jax.Array:
        """obs (..., obs_size) raw -> action (..., action_size) rad."""
        return self.distribution(obs)[0]

    def distribution(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Gaussian (mean, log_std), each (..., action_size), for stochastic use."""
        mean, log_std, _ = forward(
            self.network, self.params, self.obs_stats, obs, self.config.ppo.obs_clip
        )
        return mean, log_std


def rate_limited(policy: Any, max_step: Any, lower: Any = None, upper: Any = None) -> Any:
    """`policy` whose joint targets, clipped to [lower, upper] when given (as the env
    clips them), are moved toward the observed joints (obs[..., :A], the MARA
    observation's q), the whole displacement scaled by one factor, so that no joint is
    asked to move more than `max_step` rad (a float, or an array broadcasting against
    the batch, e.g. (E, 1) per episode): the direction in joint space is kept, where a
    servo-driven arm moving each joint at its own top speed would follow
    sign(displacement) instead. Non-finite targets pass through unchanged (the env
    counts and replaces them) and do not enter the scale. A pytree like `policy`
    (jax.tree_util.Partial)."""
    if isinstance(max_step, int | float) and not max_step > 0:
        raise ValueError(f"rate_limited: max_step={max_step!r} must be > 0 (rad per step)")
    bounds = None if lower is None else (jnp.asarray(lower), jnp.asarray(upper))
    return jax.tree_util.Partial(
        _rate_limited_call, policy, jnp.asarray(max_step, jnp.float32), bounds
    )


def _rate_limited_call(policy: Any, max_step: jax.Array, bounds: Any, obs: jax.Array):
    action = policy(obs)
    q = obs[..., : action.shape[-1]]
    finite = jnp.isfinite(action)
    target = jnp.where(finite, action, q)
    if bounds is not None:
        target = jnp.clip(target, bounds[0], bounds[1])
    delta = target - q
    big = jnp.max(jnp.abs(delta), axis=-1, keepdims=True)
    limited = q + delta * jnp.minimum(1.0, max_step / jnp.maximum(big, 1e-12))
    return jnp.where(finite, limited, action)


def make_policy(
    checkpoint_or_params: Any,
    config: TrainConfig | PPOConfig | None = None,
    obs_stats: RunningStats | None = None,
) -> Policy:
    """The deterministic policy fn(obs) -> action from any of:

    * a checkpoint path (file, or a run folder: its newest checkpoint); config is read
      from the checkpoint;
    * a `RunnerState` (training state) with its `config`;
    * flax params of `ActorCritic` with their `config` (and `obs_stats` when
      config.ppo.normalize_obs);
    * a `Policy` (returned as is).
    """
    if isinstance(checkpoint_or_params, Policy):
        return checkpoint_or_params
    if isinstance(checkpoint_or_params, str | os.PathLike):
        return load_policy(checkpoint_or_params)
    if config is None:
        raise ValueError("make_policy needs the TrainConfig the params were trained with")
    config = as_train_config(config)
    params = checkpoint_or_params
    if hasattr(params, "params") and hasattr(params, "obs_stats"):  # RunnerState
        params, obs_stats = params.params, params.obs_stats
        axis = member_axis(checkpoint_or_params)
        if axis is not None:  # a population's policy is member 0's
            params, obs_stats = jax.tree.map(
                lambda x: jnp.take(x, 0, axis=axis), (params, obs_stats)
            )
    try:
        action_size = int(params["params"]["log_std"].shape[-1])
    except (KeyError, TypeError, AttributeError) as e:
        raise ValueError(
            "make_policy: params are not those of mara_mjx.ppo.ActorCritic "
            "(no params['params']['log_std'])"
        ) from e
    if config.ppo.normalize_obs and obs_stats is None:
        raise ValueError(
            "make_policy: config.normalize_obs is true but no obs_stats were given; the policy "
            "would see unnormalised observations"
        )
    return Policy(
        params=params,
        obs_stats=obs_stats if config.ppo.normalize_obs else None,
        config=config,
        action_size=action_size,
    )


def load_policy(path: str | os.PathLike) -> Policy:
    """The deterministic `Policy` of a checkpoint file or run folder (its newest readable
    checkpoint)."""
    return policy_from_checkpoint(*load_checkpoint(find_checkpoint(path)))


def policy_from_checkpoint(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Policy:
    """The deterministic `Policy` from `mara_mjx.ppo.checkpoint.load_checkpoint` output.
    CheckpointError where its parameters or observation statistics are not finite (a
    diverged run: its NaN actions would be replaced by holding the pose, and an
    evaluation would print a normal-looking table). Every CLI that loads a policy
    (evaluate, play, export, a --seeds evaluation) comes through here."""
    try:
        config = TrainConfig.from_meta(meta)  # either layout (a pre-split flat "ppo" too)
    except (TypeError, ValueError) as e:
        raise CheckpointError(f"checkpoint holds an invalid PPO config: {e}") from e
    network = make_network(config, meta["action_size"])
    obs = jax.ShapeDtypeStruct((meta["observation_size"],), jnp.float32)
    template = jax.eval_shape(network.init, jax.random.key(0), obs, obs)
    if config.curriculum.population > 1:  # a population's policy is member 0's (members)
        arrays = {
            k: (v[0] if k.startswith(("params/", "obs_stats/")) else v) for k, v in arrays.items()
        }
    check_finite_arrays(arrays)
    params = arrays_to_state(arrays, template, prefix="params/")
    stats = None
    if config.ppo.normalize_obs:
        stats = arrays_to_state(arrays, RunningStats.create(meta["observation_size"]), "obs_stats/")
    return Policy(params=params, obs_stats=stats, config=config, action_size=meta["action_size"])


def check_finite_arrays(arrays: dict[str, np.ndarray]) -> None:
    """CheckpointError naming the policy arrays (params/..., obs_stats/...) of a
    checkpoint that hold NaN or inf."""
    bad = [
        name
        for name, value in arrays.items()
        if name.startswith(("params/", "obs_stats/"))
        and np.issubdtype(np.asarray(value).dtype, np.inexact)
        and not np.all(np.isfinite(value))
    ]
    if bad:
        shown = ", ".join(bad[:3]) + (f" and {len(bad) - 3} more" if len(bad) > 3 else "")
        raise CheckpointError(
            f"the checkpoint's policy is not finite (NaN or inf in {shown}): the run diverged; "
            "use an earlier checkpoint of the run"
        )
