"""Networks, the diagonal Gaussian and the observation normaliser (pure pieces).

The networks are those of OpenAI baselines ppo2 with `value_network='copy'`, as used
by the paper: a tanh MLP for the Gaussian mean and a separate tanh MLP of the same shape
for the value, orthogonal initialisation (gain sqrt(2) for hidden layers, 0.01 for the
policy head, 1 for the value head), zero biases, and a state-independent log standard
deviation. The Gaussian mean is the action: joint targets (rad) that the env clips to
the joint limits, either the actor's output itself (`relative_actions=False`, baselines)
or the current joint positions (the first `action_size` raw observation entries, which
the MARA observation starts with) plus the actor's output (`relative_actions=True`, so
that "stay" is the output 0). The log-std can be floored (`log_std_floor`), and chosen
observation entries hidden from both networks (`hidden_obs`). With `task_space_actions`
the actor's output is a TCP displacement that one damped-least-squares step through the
arm's Jacobian turns into the joint displacement (mara_mjx.envs.task_space). With
`ik_prior` an inverse-kinematics step toward the observed target enters as extra input
features ('features') and, with 'residual', is added to the joint displacement the actor
corrects (mara_mjx.envs.task_space.pose_step), the correction faded out near the target
with `ik_gate` (so that the IK step alone finishes the reach). With `ik_finish` the saved
policy of a position task ends with the IK step alone (task_space.finish_step) within
that distance of the target; the trainer's network has no finish. With `max_joint_step`
m > 0 the joint displacement is squashed to m tanh(delta / m), so the mean moves each
joint less than m per control step (and the trainer clips its samples to the same box),
as the real driver's servos move at most `velocity` x control_dt.

    network = make_network(config, action_size)   # a TrainConfig (mara_mjx.ppo.config)
    mean, log_std, value = forward(network, params, obs_stats, obs, config.ppo.obs_clip)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct


class MLP(nn.Module):
    """tanh MLP with orthogonal initialisation; the output layer is linear."""

    hidden_sizes: Sequence[int]
    out_size: int
    out_gain: float

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.hidden_sizes:
            x = nn.Dense(width, kernel_init=nn.initializers.orthogonal(math.sqrt(2.0)))(x)
            x = jnp.tanh(x)
        return nn.Dense(self.out_size, kernel_init=nn.initializers.orthogonal(self.out_gain))(x)


class ActorCritic(nn.Module):
    """Gaussian policy and value function with separate MLPs (no shared layers)."""

    action_size: int
    hidden_sizes: Sequence[int] = (64, 64)
    init_log_std: float = 0.0
    relative_actions: bool = False
    log_std_floor: float = -20.0
    hidden_obs: tuple[int, ...] = ()
    quat_index: int = -1
    task_space: bool = False
    max_joint_step: float = 0.0
    ik_prior: str = ""
    ik_quat_index: int = -1
    ik_gate: float = 0.0
    ik_wrap: bool = False
    ik_gate_wrap: bool = False
    ik_orient_first: bool = False
    ik_gate_roll: bool = False
    ik_orient_loose: bool = False
    ik_finish: float = 0.0
    ik_guard: bool = False
    collision_guard: float = 0.0

    @nn.compact
    def __call__(
        self, obs: jax.Array, raw_obs: jax.Array | None = None, ik: Any = None
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """obs (..., obs_size) normalised (and the raw obs when relative_actions) ->
        mean (..., A), log_std (..., A), value (...). `ik`: ik_inputs(self, raw_obs) if
        already computed (the trainer computes it once per sample), else None."""
        if self.hidden_obs:  # entries neither network sees (zero after normalisation)
            obs = obs.at[..., jnp.asarray(self.hidden_obs)].set(0.0)
        if self.ik_prior:  # the IK step toward the observed target (PolicyConfig.ik_prior)
            if raw_obs is None:
                raise ValueError("ik_prior: the network needs the raw observation")
            ik_step, wrapping = ik_inputs(self, raw_obs) if ik is None else ik
            obs = jnp.concatenate([obs, *(jnp.tanh(ik_step / s) for s in IK_FEATURE_SCALES)], -1)
        mean = MLP(self.hidden_sizes, self.action_size, 0.01, name="actor")(obs)
        if self.relative_actions:
            if raw_obs is None:
                raise ValueError("relative_actions: the network needs the raw observation")
            q = raw_obs[..., : self.action_size]
            if self.task_space:  # the output is a TCP displacement (envs/task_space.py)
                if self.action_size != 6:
                    raise ValueError(
                        f"task_space_actions needs the MARA arm's 6 joints, got {self.action_size}"
                    )
                from mara_mjx.envs.task_space import task_to_joint

                delta = task_to_joint(q, mean) - q
            else:
                delta = mean
            if self.ik_prior == "residual":
                if self.ik_gate > 0.0:  # near the target the IK step alone (PolicyConfig.ik_gate)
                    gate = ik_gate(raw_obs, self.ik_gate)
                    if self.ik_gate_wrap:  # and while it turns the flange the long way (or
                        # rolls it by more than a step: PolicyConfig.train_ik_gate_roll)
                        gate = jnp.where(wrapping, 0.0, gate)
                    delta = delta * gate[..., None]
                delta = delta + ik_step
                if self.ik_guard and self.ik_orient_first and self.ik_gate_wrap:
                    # the deployed rule: a learnt step stops at the edge of the zone where
                    # the IK step alone makes the last approach (PolicyConfig.ik_orient_first)
                    from mara_mjx.envs.task_space import ORIENT_FIRST_NEAR, stop_outside

                    delta = stop_outside(q, raw_obs[..., 6:9], delta, ORIENT_FIRST_NEAR)
            if self.ik_finish > 0.0:  # the last approach is the IK step's (PolicyConfig.ik_finish)
                from mara_mjx.envs.task_space import finish_step, stop_outside

                e = raw_obs[..., 6:9]
                near = jnp.sum(jnp.square(e), -1, keepdims=True) < self.ik_finish**2
                delta = stop_outside(q, e, delta, self.ik_finish)  # no jump into the zone
                delta = jnp.where(near, finish_step(q, e), delta)
            if self.max_joint_step > 0.0:  # |delta| < m per joint, smoothly (PolicyConfig)
                delta = self.max_joint_step * jnp.tanh(delta / self.max_joint_step)
            if self.collision_guard > 0.0:  # deployed only (PolicyConfig.collision_guard_mm)
                from mara_mjx.envs.clearance import keep_clear

                delta = keep_clear(q, delta, self.collision_guard)
            mean = q + delta
        value = MLP(self.hidden_sizes, 1, 1.0, name="critic")(obs)[..., 0]
        log_std = self.param(
            "log_std", nn.initializers.constant(self.init_log_std), (self.action_size,)
        )
        log_std = jnp.maximum(log_std, self.log_std_floor)
        return mean, jnp.broadcast_to(log_std, mean.shape), value


IK_FEATURE_SCALES = (0.002, 0.03, 0.3)
"""rad: the IK step's joint displacement enters the networks as tanh(dq / s) at each s."""


def ik_prior_step(
    raw_obs: jax.Array,
    quat_index: int,
    wrap_last: bool = False,
    orient_first: bool = False,
    flag_roll: bool = False,
    loose: bool = False,
) -> tuple[jax.Array, jax.Array]:
    """The bounded IK step (mara_mjx.envs.task_space.pose_step) toward the pose a MARA
    observation reports: q = obs[:6], e = obs[6:9], quat_err at quat_index (-1: none) ->
    (dq (..., 6), whether it takes the last joint the long way round, or with flag_roll
    still rolls it by more than a step (...); with loose, orient-first's training rule;
    task_space.pose_step_wrapping)."""
    from mara_mjx.envs.task_space import pose_step_wrapping

    quat = raw_obs[..., quat_index : quat_index + 4] if quat_index >= 0 else None
    return pose_step_wrapping(
        raw_obs[..., :6], raw_obs[..., 6:9], quat, wrap_last, orient_first, flag_roll, loose
    )


def ik_inputs(network: ActorCritic, raw_obs: jax.Array) -> tuple[jax.Array, jax.Array] | None:
    """What `network` computes from the raw observation before its MLPs: the IK step and
    its flag (ik_prior_step with the network's options), or None without ik_prior. No
    params and no gradient: the trainer computes it once per rollout sample and passes it
    to every later forward pass of that sample (the values, each epoch's minibatches)."""
    if not network.ik_prior:
        return None
    return ik_prior_step(
        raw_obs,
        network.ik_quat_index,
        network.ik_wrap,
        network.ik_orient_first,
        network.ik_gate_roll,
        network.ik_orient_loose,
    )


def ik_gate(raw_obs: jax.Array, scale: float) -> jax.Array:
    """tanh(|e| / scale) of PolicyConfig.ik_gate, e = obs[6:9] of a MARA observation -> (...)."""
    return jnp.tanh(jnp.sqrt(jnp.sum(jnp.square(raw_obs[..., 6:9]), -1) + 1e-20) / scale)


def canonical_quat(obs: jax.Array, index: int) -> jax.Array:
    """obs with the (w, x, y, z) block at `index` multiplied by the sign of its w (w >= 0;
    w = 0 counts as positive); identity when index < 0. Same rotation, continuous error."""
    if index < 0:
        return obs
    quat = obs[..., index : index + 4]
    sign = jnp.where(quat[..., :1] < 0, -1.0, 1.0).astype(obs.dtype)
    return obs.at[..., index : index + 4].set(quat * sign)


def make_network(config: Any, action_size: int, training: bool = False) -> ActorCritic:
    """The ActorCritic a TrainConfig describes (the one constructor: training, policies and
    checkpoints all build it here): the MLPs' shape from its `ppo` (PPOConfig), the
    parametrisation from its `policy` (PolicyConfig). `training`: the trainer's network,
    with the training-only rules (train_ik_gate_roll, train_ik_orient_loose) and without
    the deployed-only ones (ik_finish, the guard of ik_orient_first's zone, the collision
    guard); policies run
    the other way round. A PPOConfig alone has the default parametrisation."""
    from mara_mjx.ppo.config import as_train_config

    config = as_train_config(config)
    ppo, policy = config.ppo, config.policy
    return ActorCritic(
        action_size,
        tuple(ppo.hidden_sizes),
        ppo.init_log_std,
        policy.relative_actions,
        ppo.log_std_floor,
        tuple(policy.hidden_obs),
        policy.quat_index if policy.canonical_quat else -1,
        policy.task_space_actions,
        policy.max_joint_step,
        policy.ik_prior,
        policy.quat_index if policy.ik_prior else -1,
        policy.ik_gate,
        policy.ik_wrap,
        policy.ik_gate_wrap,
        policy.ik_orient_first,
        training and policy.train_ik_gate_roll,
        training and policy.ik_orient_first and policy.train_ik_orient_loose,
        0.0 if training else policy.ik_finish,
        not training and policy.ik_orient_first,  # its deployed guard (stop_outside)
        0.0 if training else policy.collision_guard_mm * 1e-3,  # m
    )


def forward(
    network: ActorCritic,
    params: Any,
    stats: RunningStats | None,
    obs: jax.Array,
    clip: float,
    ik: Any = None,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Raw obs (..., obs_size) -> (mean, log_std, value): canonicalise the quaternion
    block (if the network has one), normalise, then the network (with `ik`, the
    network's ik_inputs of obs if already computed)."""
    features = canonical_quat(obs, network.quat_index)
    return network.apply(params, normalize(stats, features, clip), obs, ik)


def gaussian_log_prob(mean: jax.Array, log_std: jax.Array, action: jax.Array) -> jax.Array:
    """log N(action; mean, exp(log_std)^2), summed over the last (action) axis."""
    z = (action - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * jnp.square(z) - log_std - 0.5 * math.log(2.0 * math.pi), axis=-1)


def gaussian_entropy(log_std: jax.Array) -> jax.Array:
    """Entropy (nats) of the diagonal Gaussian, summed over the last (action) axis."""
    return jnp.sum(log_std + 0.5 * math.log(2.0 * math.pi * math.e), axis=-1)


@struct.dataclass
class RunningStats:
    """Running mean and variance of observations (Chan et al.'s parallel Welford merge).

    `count` is float32: past 2^24 samples it rounds, which only perturbs the weight of a
    new batch relative to the history (irrelevant at that point)."""

    mean: jax.Array  # (obs_size,)
    var: jax.Array  # (obs_size,) population variance
    count: jax.Array  # () samples seen, starting at a tiny epsilon (baselines' RunningMeanStd)

    @classmethod
    def create(cls, size: int) -> RunningStats:
        return cls(
            mean=jnp.zeros(size, jnp.float32),
            var=jnp.ones(size, jnp.float32),
            count=jnp.array(1e-4, jnp.float32),
        )


def update_stats(stats: RunningStats, batch: jax.Array) -> RunningStats:
    """Merge a (B, obs_size) batch into the running statistics."""
    batch = batch.reshape(-1, stats.mean.shape[-1]).astype(jnp.float32)
    n = jnp.asarray(batch.shape[0], jnp.float32)
    batch_mean = jnp.mean(batch, axis=0)
    batch_var = jnp.var(batch, axis=0)
    total = stats.count + n
    delta = batch_mean - stats.mean
    mean = stats.mean + delta * n / total
    m2 = stats.var * stats.count + batch_var * n + jnp.square(delta) * stats.count * n / total
    return RunningStats(mean=mean, var=m2 / total, count=total)


def normalize(stats: RunningStats | None, obs: jax.Array, clip: float = 10.0) -> jax.Array:
    """(obs - mean) / sqrt(var + 1e-8), clipped to [-clip, clip]; identity if stats is None."""
    if stats is None:
        return obs
    z = (obs - stats.mean) / jnp.sqrt(stats.var + 1e-8)
    return jnp.clip(z, -clip, clip)
