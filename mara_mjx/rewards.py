"""The gym-gazebo2 MARA rewards, as pure functions of named quantities.

Formulas are those of the original code (spec section 4, ../shared/spec/mara-world.md):

    d      = sqrt((e_x^2 + e_y^2 + e_z^2) / 3)     RMS of the position error (m)
    theta  = 2 arccos(|quat_err_w|)                 orientation error angle, [0, pi] (rad)
    D(d)   = (exp(-a d) - exp(-a)) / (1 - exp(-a))
             + 10 (exp(-a d / done) - exp(-a / done)) / (1 - exp(-a / done))
    O(th)  = (1 + gamma - (th / pi)^beta) / (1 + gamma)
    C(d)   = delta (2 min(d, 0.5))^eta  if the step collided, else 0

    MARA: D - 1      MARAOrient: D O - 1      MARACollision: D - 1 - C
    MARACollisionOrient: D O - 1 - C

Everything is jittable and broadcasts over leading batch dimensions. The
hyperparameters travel as a `RewardParams` pytree so that a sweep over them
never recompiles.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class RewardParams:
    """Reward hyperparameters of the paper (its section 3 and appendix)."""

    alpha: jax.Array | float = 5.0
    """Distance sharpness of the core term."""
    beta: jax.Array | float = 1.5
    """Orientation exponent (MARAOrient used 1.1, MARACollisionOrient 1.5)."""
    gamma: jax.Array | float = 1.0
    """Orientation offset: O(pi) = gamma / (1 + gamma)."""
    delta: jax.Array | float = 3.0
    """Collision penalty scale."""
    eta: jax.Array | float = 0.03
    """Collision penalty exponent."""
    done: jax.Array | float = 0.02
    """Distance scale (m) of the sharp precision bonus."""


def rms_distance(error: jax.Array) -> jax.Array:
    """d: RMS over the last axis of a (..., 3) error vector (m), not its Euclidean norm."""
    return jnp.sqrt(jnp.mean(jnp.square(error), axis=-1))


def orientation_angle(quat_err: jax.Array) -> jax.Array:
    """theta = 2 arccos(|w|) of a (..., 4) (w, x, y, z) error quaternion, in [0, pi] rad."""
    return 2.0 * jnp.arccos(jnp.clip(jnp.abs(quat_err[..., 0]), 0.0, 1.0))


def distance_term(d: jax.Array, alpha: jax.Array, done: jax.Array) -> jax.Array:
    """D(d): 11 at d = 0, 0 at d = 1 m."""
    smooth = (jnp.exp(-alpha * d) - jnp.exp(-alpha)) / (1.0 - jnp.exp(-alpha))
    sharp = (jnp.exp(-alpha * d / done) - jnp.exp(-alpha / done)) / (1.0 - jnp.exp(-alpha / done))
    return smooth + 10.0 * sharp


def orientation_factor(theta: jax.Array, beta: jax.Array, gamma: jax.Array) -> jax.Array:
    """O(theta): 1 when aligned, gamma / (1 + gamma) when upside down."""
    return (1.0 + gamma - jnp.power(theta / jnp.pi, beta)) / (1.0 + gamma)


def collision_penalty(
    d: jax.Array, collided: jax.Array, delta: jax.Array, eta: jax.Array
) -> jax.Array:
    """C: delta (2 min(d, 0.5))^eta on a colliding step, else 0."""
    penalty = delta * jnp.power(2.0 * jnp.minimum(d, 0.5), eta)
    return jnp.where(collided, penalty, 0.0)


def reward(
    d: jax.Array,
    theta: jax.Array,
    collided: jax.Array,
    params: RewardParams,
    *,
    orientation: bool,
    collision: bool,
) -> jax.Array:
    """The task reward. `orientation` and `collision` pick the task (static flags).

    Args:
      d: RMS position error (m).
      theta: orientation error angle (rad); ignored unless `orientation`.
      collided: whether this step collided (bool); ignored unless `collision`.
      params: the hyperparameters.
    Returns:
      r, at most 10 (d = 0, theta = 0).
    """
    r = distance_term(d, params.alpha, params.done)
    if orientation:
        r = r * orientation_factor(theta, params.beta, params.gamma)
    r = r - 1.0
    if collision:
        r = r - collision_penalty(d, collided, params.delta, params.eta)
    return r
