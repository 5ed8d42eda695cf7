"""Quaternion helpers, (w, x, y, z) convention as in MuJoCo. Broadcast over leading axes."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def quat_mul(a: jax.Array, b: jax.Array) -> jax.Array:
    """Hamilton product a (x) b."""
    return _hamilton(jnp, a, b)


def quat_mul_np(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a (x) b in numpy (host side: target tables)."""
    return _hamilton(np, a, b)


def _hamilton(xp: Any, a: Any, b: Any) -> Any:
    """a (x) b with the array module `xp` (jax.numpy or numpy; mara_mjx/deploy/ik_numpy.py
    holds a numpy copy, as the robot-side runner imports no mara_mjx module)."""
    aw, ax, ay, az = xp.moveaxis(a, -1, 0)
    bw, bx, by, bz = xp.moveaxis(b, -1, 0)
    return xp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conj(q: jax.Array) -> jax.Array:
    return q * jnp.array([1.0, -1.0, -1.0, -1.0], q.dtype)


def quat_canonical(q: jax.Array) -> jax.Array:
    """The same rotation with w >= 0."""
    return jnp.where(q[..., :1] < 0, -q, q)


def quat_to_euler(q: jax.Array) -> jax.Array:
    """Roll, pitch, yaw (rad): the x, y, z angles of a static-axes x-y-z rotation (ROS tf's
    default 'sxyz'), the convention of gym-gazebo2's per-axis orientation errors."""
    w, x, y, z = jnp.moveaxis(q, -1, 0)
    roll = jnp.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = jnp.arcsin(jnp.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = jnp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return jnp.stack([roll, pitch, yaw], axis=-1)


def quat_to_mat_np(quat: np.ndarray) -> np.ndarray:
    """(..., 4) (w, x, y, z) unit quaternions -> (..., 3, 3) rotation matrices (numpy, host side:
    pose tables, constants at construction)."""
    w, x, y, z = np.moveaxis(np.asarray(quat, float), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
