"""Where the policy explores, and how a point of its Gaussian becomes the env's action.

The env's action is always absolute joint targets (rad, clipped by the env to the joint
limits), and the actor always proposes a joint-space step: the joint targets m = q + y
(`relative_actions`, y the actor's output). `PPOConfig.exploration` chooses the space of
the Gaussian around it:

* 'joint' (baselines): the Gaussian is over joint targets, mean m, one log-std per
  joint; `env_action` is the identity.
* 'task': the Gaussian is over the TCP's displacement u, a 6-D twist (world-frame
  translation in units of task_scale[0] metres, world-frame rotation vector in units of
  task_scale[1] rad), one log-std per coordinate. With J_s = S^-1 J(q) the TCP's
  geometric Jacobian in those units and M its damped least-squares inverse
  (Wampler 1986; Buss 2004, "Introduction to inverse kinematics with Jacobian transpose,
  pseudoinverse and damped least squares methods"):

      M(q)   = J_s^T (J_s J_s^T + lambda^2 I)^-1                    lambda = task_damping
      mean   = J_s (m - q)                 the actor's step as a TCP displacement
      action = q + M u                     joint targets for a point u of the Gaussian

  so the deterministic action is q + M J_s y, which is q + y up to the damping (M J_s
  has eigenvalues s^2 / (s^2 + lambda^2) for J_s's singular values s: above 0.99 in the
  arm's working configurations, 0 along the directions that a singular configuration
  such as the straight-up reset pose cannot move the TCP in).

Why 'task' (benchmarks/NOTES.md, section 17): PPO maximises the reward averaged over its
own noise. Independent joint noise of a given size moves the TCP more in some arm
configurations than in others, and the reward's position term is sharp (millimetres), so
the noise-averaged reward favours configurations that the noise disturbs less, by more
than the orientation term is worth at a few degrees; measured, the settled policies sit
1-5 deg off the target orientation where the noise-averaged reward is as high as, or
higher than, at the exact pose. Noise defined on the TCP is the same in every
configuration, so the noise-averaged reward is highest at the exact pose again.

q is the observation's first six entries (the MARA observation's joint positions; under
domain randomisation the encoders' reading, as on a real arm) and J comes from
`mara_mjx.envs.chain` (the shipped model's kinematics). Both maps are deterministic
functions of the observation, so PPO's likelihood ratios are those of u and nothing else
in the algorithm changes; the bound loss acts on the joint targets.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

EXPLORATION_SPACES = ("joint", "task")
NUM_JOINTS = 6


def _scale_vector(task_scale: tuple[float, float]) -> jax.Array:
    """(6,) the unit of each twist coordinate: metres for translation, rad for rotation."""
    pos, rot = task_scale
    return jnp.array([pos] * 3 + [rot] * 3, jnp.float32)


def _scaled_jacobian(q: jax.Array, task_scale: tuple[float, float]) -> jax.Array:
    """J_s(q) (6, 6): the TCP's geometric Jacobian with rows in units of task_scale."""
    from mara_mjx.envs.chain import mara_chain  # the shipped arm's kinematics

    return mara_chain().jacobian(q) / _scale_vector(task_scale)[:, None]


def dls_inverse(j: jax.Array, damping: float) -> jax.Array:
    """M = J^T (J J^T + damping^2 I)^-1 for a square J (n, n)."""
    gram = j @ j.T + (damping**2) * jnp.eye(j.shape[0], dtype=j.dtype)
    return jnp.linalg.solve(gram, j).T  # gram is symmetric: (gram^-1 J)^T = J^T gram^-1


def twist_mean(obs: jax.Array, joint_mean: jax.Array, task_scale: tuple[float, float]) -> jax.Array:
    """The Gaussian's mean (..., 6) in twist units for joint targets `joint_mean` (..., 6)
    proposed at raw `obs` (..., obs_size): J_s(q) (joint_mean - q)."""

    def one(q: jax.Array, target: jax.Array) -> jax.Array:
        return _scaled_jacobian(q, task_scale) @ (target - q)

    return jnp.vectorize(one, signature="(n),(n)->(n)")(obs[..., :NUM_JOINTS], joint_mean)


def env_action(config: Any, obs: jax.Array, action: jax.Array) -> jax.Array:
    """The env's action (..., 6) rad for a point `action` (..., A) of the policy's Gaussian
    at raw `obs` (..., obs_size): the identity for exploration 'joint', q + M(q) u for
    'task'."""
    if config.exploration == "joint":
        return action

    def one(q: jax.Array, twist: jax.Array) -> jax.Array:
        m = dls_inverse(_scaled_jacobian(q, config.task_scale), config.task_damping)
        return q + m @ twist

    return jnp.vectorize(one, signature="(n),(n)->(n)")(obs[..., :NUM_JOINTS], action)
