"""GAE and the PPO loss as pure functions of arrays (baselines ppo2 semantics).

Truncation vs termination (spec: these tasks almost always truncate):

    next_value[t] = V(final_obs[t]) * (1 - terminated[t])

where final_obs[t] is the observation the step produced *before* any auto-reset, so it is
the next observation on ordinary steps and the last observation of the episode on
truncated ones. Then

    delta[t] = reward[t] + gamma * next_value[t] - value[t]
    A[t]     = delta[t] + gamma * lambda * (1 - done[t]) * A[t + 1],   done = terminated | truncated

i.e. a truncated step is bootstrapped from the value of its final observation, a
terminated one is not, and advantages never leak across an episode boundary.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


def gae(
    reward: jax.Array,
    value: jax.Array,
    next_value: jax.Array,
    done: jax.Array,
    gamma: float,
    gae_lambda: float,
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimation over a (T, ...) rollout, time first.

    Args:
      reward: (T, N) reward of each step.
      value: (T, N) V(obs[t]).
      next_value: (T, N) V(final_obs[t]) * (1 - terminated[t]) (module docstring).
      done: (T, N) bool, the episode ended at step t (terminated or truncated).
    Returns:
      advantages (T, N) and value targets (returns) = advantages + value.
    """
    not_done = 1.0 - done.astype(reward.dtype)
    delta = reward + gamma * next_value - value

    def backward(carry: jax.Array, x: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        delta_t, not_done_t = x
        advantage = delta_t + gamma * gae_lambda * not_done_t * carry
        return advantage, advantage

    _, advantages = jax.lax.scan(
        backward, jnp.zeros_like(delta[0]), (delta, not_done), reverse=True
    )
    return advantages, advantages + value


class LossInfo(NamedTuple):
    """Scalars of one minibatch."""

    total: jax.Array
    policy: jax.Array
    value: jax.Array
    entropy: jax.Array
    approx_kl: jax.Array  # 0.5 E[(log pi_old - log pi)^2], as baselines ppo2
    clip_frac: jax.Array  # fraction of samples with |ratio - 1| > clip_eps


def ppo_loss(
    log_prob: jax.Array,
    value: jax.Array,
    entropy: jax.Array,
    old_log_prob: jax.Array,
    old_value: jax.Array,
    advantages: jax.Array,
    returns: jax.Array,
    *,
    clip_eps: float,
    vf_coef: float,
    ent_coef: float,
    clip_value: bool = True,
    normalize_advantages: bool = True,
) -> tuple[jax.Array, LossInfo]:
    """The PPO-clip loss of baselines ppo2 on one (B,) minibatch.

    policy = E[max(-A r, -A clip(r, 1 - eps, 1 + eps))],  r = exp(log_prob - old_log_prob)
    value  = 0.5 E[max((v - R)^2, (v_clipped - R)^2)],  v_clipped = v_old + clip(v - v_old, +-eps)
             (0.5 E[(v - R)^2] without clip_value)
    total  = policy + vf_coef value - ent_coef E[entropy]

    A is normalised over the minibatch (mean 0, std 1) when normalize_advantages.
    """
    if normalize_advantages:
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    log_ratio = log_prob - old_log_prob
    ratio = jnp.exp(log_ratio)
    policy_loss = jnp.mean(
        jnp.maximum(-advantages * ratio, -advantages * jnp.clip(ratio, 1 - clip_eps, 1 + clip_eps))
    )
    value_error = jnp.square(value - returns)
    if clip_value:
        clipped = old_value + jnp.clip(value - old_value, -clip_eps, clip_eps)
        value_error = jnp.maximum(value_error, jnp.square(clipped - returns))
    value_loss = 0.5 * jnp.mean(value_error)
    entropy = jnp.mean(entropy)
    total = policy_loss + vf_coef * value_loss - ent_coef * entropy
    info = LossInfo(
        total=total,
        policy=policy_loss,
        value=value_loss,
        entropy=entropy,
        approx_kl=0.5 * jnp.mean(jnp.square(log_ratio)),
        clip_frac=jnp.mean((jnp.abs(ratio - 1.0) > clip_eps).astype(jnp.float32)),
    )
    return total, info


def bound_loss(mean: jax.Array, lower: jax.Array, upper: jax.Array) -> jax.Array:
    """E[sum_j relu(mean_j - upper_j)^2 + relu(lower_j - mean_j)^2] (rad^2): the loss
    CurriculumConfig.bound_coef weighs."""
    excess = jax.nn.relu(mean - upper) + jax.nn.relu(lower - mean)
    return jnp.mean(jnp.sum(jnp.square(excess), axis=-1))
