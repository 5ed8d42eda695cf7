"""Task-space actions: a TCP displacement mapped to joint targets through the arm's Jacobian.

The env's action stays what the spec says, absolute joint targets (rad). A policy may
instead *parametrise* its joint targets by a TCP displacement (PPOConfig.task_space_actions):
its output u (6,) is read as a small TCP move, position then rotation, in the world frame,

    dx = (u[:3] * POSITION_SCALE, u[3:] * ROTATION_SCALE)      (m, rad)

and turned into joint targets by one damped-least-squares step at the observed joints q,

    q_target = q + J(q)^T (J(q) J(q)^T + DAMPING^2 I)^-1 dx

with J the TCP's geometric Jacobian (6, 6) of the *nominal* arm (envs/chain.py: the
policy knows the arm's drawing, not a randomised one's true geometry; the same q the
policy observes). This is the resolved-rate / operational-space parametrisation of
robosuite's OSC controllers and of classic visual servoing: "move the tool toward the
target and turn it onto the target's orientation" becomes a nearly linear function of
the observation (dx = -k (e, rotation error)), whatever the arm's posture, so the position
and the orientation each have their own action directions even where joint space makes
them hard to tell apart (benchmarks/NOTES.md section 20). Near a singularity the damping
keeps the step bounded (|dq| <= |dx| / (2 DAMPING)).

    q_target = task_to_joint(q, u)          # (..., 6), (..., 6) -> (..., 6) rad
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from mara_mjx.envs.chain import Chain

POSITION_SCALE = 0.1
"""m of TCP motion per unit of the policy's position output."""
ROTATION_SCALE = 0.5
"""rad of TCP rotation per unit of the policy's rotation output."""
DAMPING = 0.02
"""Damped-least-squares damping (m or rad; J J^T + DAMPING^2 I)."""


@functools.lru_cache(maxsize=1)
def nominal_chain() -> Chain:
    """The kinematic chain of the MARA model in the package's assets (built once)."""
    from mara_mjx.envs.arm import load_model  # arm imports chain (through lean): no cycle

    return Chain.from_model(load_model())


def dls_step(jac: jax.Array, dx: jax.Array, damping: float = DAMPING) -> jax.Array:
    """jac (6, 6), dx (6,) -> dq = J^T (J J^T + damping^2 I)^-1 dx (6,)."""
    gram = jac @ jac.T + (damping**2) * jnp.eye(jac.shape[0], dtype=jac.dtype)
    return jac.T @ jnp.linalg.solve(gram, dx)


def task_to_joint(q: jax.Array, u: jax.Array) -> jax.Array:
    """q (..., 6) rad observed joints, u (..., 6) policy output -> joint targets (..., 6)."""
    chain = nominal_chain()
    scale = jnp.array([POSITION_SCALE] * 3 + [ROTATION_SCALE] * 3, jnp.float32)

    def one(q1: jax.Array, u1: jax.Array) -> jax.Array:
        jac = chain.jacobian(jax.lax.stop_gradient(q1))
        return q1 + dls_step(jax.lax.stop_gradient(jac), u1 * scale)

    return jnp.vectorize(one, signature="(6),(6)->(6)")(q, u)
