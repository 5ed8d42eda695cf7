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

Valid ranges (`RANGES`; outside them the task changes meaning or float32 arithmetic
breaks, so they are rejected with an error naming the parameter, its value and its
range). The spec's section 4 gives the lower bounds and alpha's 80; the others are
derived here from the float32 the rewards are computed in (eps = 2^-24 ~ 6e-8 near 1):

    alpha  [1e-3, 80]   exp(-alpha) must stay a normal float32 (> 2^-126 = exp(-87.3);
                        XLA flushes smaller values to 0 and D no longer varies out to
                        1 m); 1e300 becomes inf and every reward -1. Below 1e-3 the
                        (exp(-a d) - exp(-a)) / (1 - exp(-a)) cancellation costs more
                        than 1e-4 relative, and 1 - exp(-a) is 0 (NaN) below ~3e-8.
    done   [1e-6, 1] m  the precision bonus' radius: at 1 m it equals the smooth term
                        (D is normalised over 1 m), past it it is no longer the sharp
                        one and alpha/done -> 0 cancels as above; below 1e-6 m (about
                        10 float32 steps of a 1 m coordinate) it is narrower than a
                        position can resolve, so never earned.
    beta   (0, 20]      0 makes O constant (0^0 = 1), < 0 makes it infinite at theta = 0;
                        past 20, (1/2)^beta < 2^-20 ~ 1e-6, so O is within 1e-6 of 1 for
                        every theta up to pi/2: the orient tasks stop rewarding it.
    gamma  [0, 1e6]     O(pi) = gamma / (1 + gamma): below 0 O turns negative and a
                        misoriented arm is paid to move away; O's whole range is
                        1 / (1 + gamma), below ~1e-6 (a few float32 steps) past 1e6.
    delta  [0, 1e6]     the collision penalty's scale: < 0 pays for collisions; past
                        1e6 a colliding step's float32 r = D - 1 - C rounds away the
                        distance term's detail (the float32 step at 1e6 is 0.06).
    eta    [0, 1]       (2 min(d, 0.5))^eta with a base in [0, 1]: < 0 makes the penalty
                        explode near the target (infinite at d = 0); <= 1 keeps
                        C(d) >= 2 delta d, so a collision near the target still costs
                        (at eta = 5 a collision 1 mm away costs 3e-14 delta).

Every value must be a finite real number. The check runs on concrete values: Python
numbers and numpy arrays given to `RewardParams(...)` (and so to `mara_mjx.make`,
`EnvConfig` and the CLIs' `--env.alpha`-style flags). jax arrays are not checked there:
inside `jit`/`vmap` they are tracers, whose values do not exist yet, and reading a device
array back would stall JAX's asynchronous dispatch. Build params from checked Python
numbers (as `make()` does), or call `check_reward_params(params)` on concrete arrays.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


class Range(NamedTuple):
    """low <= value <= high (low < value where `low_open`)."""

    low: float
    high: float
    low_open: bool = False

    def contains(self, value: float) -> bool:
        above = value > self.low if self.low_open else value >= self.low
        return math.isfinite(value) and above and value <= self.high

    def __str__(self) -> str:
        return f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}]"


RANGES: dict[str, Range] = {
    "alpha": Range(1e-3, 80.0),
    "beta": Range(0.0, 20.0, low_open=True),
    "gamma": Range(0.0, 1e6),
    "delta": Range(0.0, 1e6),
    "eta": Range(0.0, 1.0),
    "done": Range(1e-6, 1.0),
}
"""Each reward hyperparameter's valid range (why: the module docstring)."""


def check_reward_value(name: str, value: Any) -> None:
    """ValueError naming `name`, `value` and its range unless `value` (a number or an
    array of them) lies in `RANGES[name]` everywhere."""
    try:
        values = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise ValueError(
            f"reward hyperparameter {name}={value!r} must be a number in {RANGES[name]}"
        ) from None
    bad = [float(v) for v in values if not RANGES[name].contains(float(v))]
    if bad:
        shown = repr(bad[0]) if values.size == 1 else f"{bad[0]!r} (one of {values.size} values)"
        raise ValueError(
            f"reward.{name}={shown} is outside its valid range "
            f"{RANGES[name]} (finite numbers only; why: mara_mjx.envs.rewards)"
        )


def _concrete(value: Any) -> bool:
    """A value whose numbers are on the host: Python and numpy numbers and arrays (not
    jax arrays or tracers, nor the placeholders JAX puts in pytrees, e.g. None)."""
    if isinstance(value, bool):
        return False
    return isinstance(value, int | float | np.number | np.ndarray)


def check_reward_params(params: Any) -> None:
    """ValueError unless every hyperparameter of `params` (a RewardParams, or a mapping
    of some of their names to values) lies in its range; jax arrays are read back
    (call this on concrete values, never inside jit)."""
    items = params.items() if isinstance(params, dict) else vars(params).items()
    for name, value in items:
        if name not in RANGES:
            raise ValueError(f"unknown reward hyperparameter {name!r}; valid are {list(RANGES)}")
        check_reward_value(name, np.asarray(jax.device_get(value)))


@struct.dataclass
class RewardParams:
    """Reward hyperparameters of the paper (its section 3 and appendix). Python and numpy
    values are checked against `RANGES` at construction (ValueError); jax arrays are not
    (tracers have no value yet: see the module docstring)."""

    alpha: jax.Array | float = 5.0
    """Distance sharpness of the core term, in [1e-3, 80]."""
    beta: jax.Array | float = 1.5
    """Orientation exponent, in (0, 20] (MARAOrient used 1.1, MARACollisionOrient 1.5)."""
    gamma: jax.Array | float = 1.0
    """Orientation offset, in [0, 1e6]: O(pi) = gamma / (1 + gamma)."""
    delta: jax.Array | float = 3.0
    """Collision penalty scale, in [0, 1e6] (0: collisions cost nothing extra)."""
    eta: jax.Array | float = 0.03
    """Collision penalty exponent, in [0, 1]: C = delta (2 min(d, 0.5))^eta."""
    done: jax.Array | float = 0.02
    """Distance scale (m) of the sharp precision bonus, in [1e-6, 1]."""

    def __post_init__(self):
        # also runs when JAX rebuilds the pytree (tracers, None placeholders): those skip
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if _concrete(value):
                check_reward_value(f.name, value)


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
