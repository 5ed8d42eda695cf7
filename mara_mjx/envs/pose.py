"""What the tasks need from one kinematics pass (MJX's or the lean one)."""

from __future__ import annotations

from typing import NamedTuple

import jax


class ArmPose(NamedTuple):
    """What the tasks need from one kinematics pass."""

    tcp_pos: jax.Array  # (3,) m, world frame
    tcp_quat: jax.Array  # (4,) (w, x, y, z), w >= 0
    tcp_jac: jax.Array  # (3, 6) d tcp_pos / d q, world frame
    collided: jax.Array  # () bool: any listed contact pair penetrates
