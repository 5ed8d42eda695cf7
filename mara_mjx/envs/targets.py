"""Target poses for the random-target tasks: tables of reachable, collision-free TCP poses.

Every pose in a table is the forward kinematics of a joint configuration inside the joint
limits that C MuJoCo finds collision-free (the same contact pairs as the env), so every
target a random-target task draws can be reached exactly, without collision.

The region (`TargetRegion`, from the EnvConfig fields target_min, target_max, target_quat,
target_spread_deg):
  * position: the TCP lies in the box [target_min, target_max] (m, world frame);
  * orientation: the flange orientation is within target_spread_deg of the reference
    target_quat (the rotation angle of quat (x) conj(reference)); 180 allows any.

How a table is made (`candidates`, host side, numpy + C MuJoCo, no JAX):
  1. Proposals: q1..q3 uniform in their limits; an orientation R drawn uniformly (Haar
     measure) within the spread around the reference; the wrist (motor4 +z, motor5 -x,
     motor6 +z, a z-x-z Euler chain) solved in closed form so that the flange has
     orientation R, one of its two solutions at random, kept if inside the joint limits.
     Drawing the wrist this way instead of uniformly is what makes narrow spreads cheap:
     the rotations within 30 degrees of one orientation are 0.75% of all rotations.
  2. Numpy forward kinematics of the chain (body offsets and joint axes of the model)
     keeps the proposals whose TCP is inside the box (about 2% for the default box).
  3. C MuJoCo `mj_kinematics` + `mj_collision` on those: the stored position (TCP site)
     and orientation (flange, the env's tcp_quat) are MuJoCo's; colliding
     configurations and any pose outside the region (checked again on MuJoCo's numbers)
     are dropped.
  Chunks of proposals are drawn until enough poses are found or `MAX_PROPOSALS` were
  tried; none found is a ValueError naming the fields (a box below the table top or out
  of the arm's reach fails at once). A training table of K poses draws K times with
  replacement from up to 4 K candidates (fewer only for tiny regions); evaluation poses
  are distinct. Cost: about 0.5 s for the default Orient region (tables of 1024 poses
  from 4096 candidates, about 180,000 proposals), 1-2 s for any orientation.

Position balance: the proposals crowd some parts of the box (where many joint
configurations land), so the tables draw from the candidates with weights 1 / (number
of candidates in the same cell of a 6 x 6 x 6 grid over the box): every reachable cell
is about equally likely.

Orientations are stored in the hemisphere of the reference (dot(quat, reference) >= 0),
so nearby orientations have nearby quaternions.

Seeds (numpy SeedSequence(seed, spawn_key=(stream,))): training tables use stream
`TRAIN_STREAM`, evaluation poses `EVAL_STREAM`; the two streams are independent whatever
the seeds, and the poses are continuous random draws, so evaluation poses are never
training poses (the evaluation reports the distance to the nearest training pose).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import mujoco
import numpy as np

from mara_mjx.envs.arm import JOINTS, TABLE_TOP_Z
from mara_mjx.envs.geometry import quat_mul_np
from mara_mjx.envs.geometry import quat_to_mat_np as _quat_to_mat

TRAIN_STREAM = 0
EVAL_STREAM = 1
CHUNK = 16384
"""Proposals per numpy batch."""
MAX_PROPOSALS = 1_000_000
"""Proposals tried before a region counts as (nearly) empty."""
GRID = 6
"""Cells per axis of the box for the position balance."""
CANDIDATES_PER_POSE = 4
"""A training table of K poses draws from up to 4 K distinct candidates."""


@dataclasses.dataclass(frozen=True)
class TargetRegion:
    """Where targets are drawn: TCP position in a box, orientation near a reference."""

    low: tuple[float, float, float]  # m, world frame
    high: tuple[float, float, float]  # m, world frame
    reference_quat: tuple[float, float, float, float]  # (w, x, y, z), unit
    spread_deg: float  # largest rotation from the reference, [0, 180]

    @classmethod
    def from_config(cls, config) -> TargetRegion:
        """The region of an EnvConfig (target_min, target_max, target_quat,
        target_spread_deg)."""
        quat = np.asarray(config.target_quat, float)
        return cls(
            tuple(map(float, config.target_min)),
            tuple(map(float, config.target_max)),
            tuple(map(float, quat / np.linalg.norm(quat))),
            float(config.target_spread_deg),
        )

    def contains(self, pos: np.ndarray, quat: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """(N,) bool: pos (N, 3) inside the box and quat (N, 4) within the spread."""
        pos, quat = np.atleast_2d(pos), np.atleast_2d(quat)
        inside = np.all((pos >= np.subtract(self.low, tol)) & (pos <= np.add(self.high, tol)), 1)
        return inside & (angle_to(quat, self.reference_quat) <= np.radians(self.spread_deg) + 1e-6)

    def describe(self) -> str:
        return (
            f"target_min={list(self.low)}, target_max={list(self.high)}, "
            f"target_spread_deg={self.spread_deg:g} around target_quat="
            f"{[round(x, 4) for x in self.reference_quat]}"
        )


class PoseTable(NamedTuple):
    """Poses (host side, float64) and the joint configurations they come from."""

    q: np.ndarray  # (M, 6) rad, inside the joint limits, collision-free
    pos: np.ndarray  # (M, 3) m, TCP position, world frame
    quat: np.ndarray  # (M, 4) (w, x, y, z) flange orientation, dot(quat, reference) >= 0

    def __len__(self) -> int:
        return len(self.q)

    def take(self, idx: np.ndarray) -> PoseTable:
        return PoseTable(self.q[idx], self.pos[idx], self.quat[idx])


# ---------------------------------------------------------------------------- rotations
def angle_to(quat: np.ndarray, reference) -> np.ndarray:
    """(N,) rad: rotation angle between unit quats (N, 4) and one reference (4,)."""
    dot = np.abs(np.atleast_2d(quat) @ np.asarray(reference, float))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def _rotate(rot: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """rot (N, 3, 3) @ (rotation by angle (N,) about the unit `axis` (3,)). About a
    coordinate axis (MARA's joints) only two columns mix, far cheaper than a matmul."""
    k = np.flatnonzero(np.abs(axis) > 0.5)
    if np.count_nonzero(axis) == 1:
        k = int(k[0])
        i, j = (k + 1) % 3, (k + 2) % 3
        c, s = np.cos(angle)[:, None], np.sign(axis[k]) * np.sin(angle)[:, None]
        out = np.array(rot)
        out[:, :, i] = c * rot[:, :, i] + s * rot[:, :, j]
        out[:, :, j] = c * rot[:, :, j] - s * rot[:, :, i]
        return out
    x, y, z = axis
    c, s = np.cos(angle), np.sin(angle)
    t = 1.0 - c
    rows = [
        [c + x * x * t, x * y * t - z * s, x * z * t + y * s],
        [y * x * t + z * s, c + y * y * t, y * z * t - x * s],
        [z * x * t - y * s, z * y * t + x * s, c + z * z * t],
    ]
    return rot @ np.stack([np.stack(r, -1) for r in rows], -2)


def random_rotations(rng: np.random.Generator, n: int, spread: float) -> np.ndarray:
    """(n, 4) unit quats uniform (Haar measure) among rotations of angle <= spread (rad).
    The angle's density on [0, pi] is (1 - cos t) / pi, so its CDF restricted to
    [0, spread] is (t - sin t) / (spread - sin spread), inverted by interpolation."""
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    if spread <= 0:
        return np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    grid = np.linspace(0.0, spread, 2049)
    cdf = (grid - np.sin(grid)) / (spread - np.sin(spread))
    angle = np.interp(rng.uniform(size=n), cdf, grid)
    return np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], 1)


# ------------------------------------------------------------------------- kinematics
class _Chain:
    """The arm's serial chain from the model, for vectorised numpy kinematics."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        self.site = model.site("tcp").id
        self.flange = model.body("motor6_link").id
        bodies = [model.joint(n).bodyid[0] for n in JOINTS]
        chain, b = [], self.flange
        while b != 0:
            chain.append(b)
            b = model.body_parentid[b]
        self.bodies = chain[::-1]  # base .. flange
        if [b for b in self.bodies if model.body_jntadr[b] >= 0] != bodies:
            raise ValueError("expected the joints motor1..motor6 on the chain base..flange")
        self.lower = model.jnt_range[:, 0].copy()
        self.upper = model.jnt_range[:, 1].copy()
        self.axes = model.jnt_axis.copy()
        if np.any(model.jnt_pos != 0):
            raise ValueError("the pose tables assume every joint at its body's origin")
        # The closed-form wrist needs motor4 = +z, motor5 = -x, motor6 = +z and unrotated
        # body frames from motor3_link on (spec section 1).
        wrist = [self.axes[3], self.axes[4], self.axes[5]]
        if not np.allclose(wrist, [[0, 0, 1], [-1, 0, 0], [0, 0, 1]]) or not np.allclose(
            model.body_quat[self.bodies[-3:]], [1, 0, 0, 0]
        ):
            raise ValueError("the pose tables assume MARA's z-x-z wrist (spec section 1)")

    def forward(self, q: np.ndarray, upto: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """TCP position (N, 3) and flange rotation (N, 3, 3) at joint positions q (N, 6);
        with `upto`, the origin and rotation of the body of joint `upto` instead."""
        m = self.model
        n = len(q)
        rot = np.broadcast_to(np.eye(3), (n, 3, 3))
        pos = np.zeros((n, 3))
        for b in self.bodies:
            pos = pos + np.einsum("nij,j->ni", rot, m.body_pos[b])
            if not np.array_equal(m.body_quat[b], [1.0, 0.0, 0.0, 0.0]):
                rot = rot @ _quat_to_mat(m.body_quat[b])
            j = m.body_jntadr[b]
            if j >= 0:
                rot = _rotate(rot, self.axes[j], q[:, j])
                if upto is not None and j == upto:
                    return pos, rot
        return pos + np.einsum("nij,j->ni", rot, m.site_pos[self.site]), rot

    def solve_wrist(self, q123: np.ndarray, rot: np.ndarray, flip: np.ndarray) -> np.ndarray:
        """(N, 6) joint configurations with q1..q3 given and the wrist chosen so that the
        flange rotation is `rot` (N, 3, 3); `flip` (N,) picks the second solution."""
        q = np.concatenate([q123, np.zeros((len(q123), 3))], 1)
        _, rot3 = self.forward(q, upto=2)
        # Rz(a) Rx(b) Rz(c) = M: third column (sin a sin b, -cos a sin b, cos b),
        # third row (sin b sin c, sin b cos c, cos b).
        wrist = np.swapaxes(rot3, 1, 2) @ rot
        b = np.arccos(np.clip(wrist[:, 2, 2], -1.0, 1.0))
        a = np.arctan2(wrist[:, 0, 2], -wrist[:, 1, 2])
        c = np.arctan2(wrist[:, 2, 0], wrist[:, 2, 1])
        a, b, c = np.where(flip, a + np.pi, a), np.where(flip, -b, b), np.where(flip, c + np.pi, c)
        wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
        q[:, 3], q[:, 4], q[:, 5] = wrap(a), -b, wrap(c)  # motor5 turns about -x
        return q


def _canonical(quat: np.ndarray, reference) -> np.ndarray:
    """Quats (N, 4) in the hemisphere of `reference`."""
    sign = np.where(quat @ np.asarray(reference, float) < 0, -1.0, 1.0)
    return quat * sign[:, None]


# ------------------------------------------------------------------------- the tables
def candidates(
    model: mujoco.MjModel,
    region: TargetRegion,
    count: int,
    seed: int,
    stream: int = TRAIN_STREAM,
    max_proposals: int = MAX_PROPOSALS,
) -> PoseTable:
    """Up to `count` distinct collision-free poses in `region` (fewer only if
    `max_proposals` ran out first). ValueError naming the fields if none is found."""
    chain = _Chain(model)
    _check_reach(chain, region)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stream,)))
    data = mujoco.MjData(model)
    ref = np.asarray(region.reference_quat, float)
    spread = np.radians(region.spread_deg)
    low, high = np.asarray(region.low), np.asarray(region.high)
    found: list[PoseTable] = []
    total, tried = 0, 0
    while total < count and tried < max_proposals:
        n = CHUNK
        tried += n
        q123 = rng.uniform(chain.lower[:3], chain.upper[:3], (n, 3))
        quat = quat_mul_np(random_rotations(rng, n, spread), ref)
        q = chain.solve_wrist(q123, _quat_to_mat(quat), rng.uniform(size=n) < 0.5)
        ok = np.all((q >= chain.lower) & (q <= chain.upper), 1)
        pos, _ = chain.forward(q)
        ok &= np.all((pos >= low) & (pos <= high), 1)
        keep = []
        for i in np.flatnonzero(ok):
            data.qpos[:] = q[i]
            mujoco.mj_kinematics(model, data)
            mujoco.mj_collision(model, data)
            if data.ncon and np.any(data.contact.dist[: data.ncon] < 0):
                continue
            keep.append((data.site_xpos[chain.site].copy(), data.xquat[chain.flange].copy(), i))
        if not keep:
            continue
        p = np.array([k[0] for k in keep])
        r = _canonical(np.array([k[1] for k in keep]), ref)
        idx = np.array([k[2] for k in keep])
        inside = region.contains(p, r)
        found.append(PoseTable(q[idx[inside]], p[inside], r[inside]))
        total += int(inside.sum())
    if total == 0:
        _empty(
            region,
            "no collision-free pose inside the joint limits has its TCP in the box and its "
            f"orientation within the spread ({tried} joint configurations tried)",
        )
    table = PoseTable(*(np.concatenate(parts)[:count] for parts in zip(*found, strict=True)))
    return table


def _empty(region: TargetRegion, why: str) -> None:
    raise ValueError(
        f"the target region is empty: {why} ({region.describe()}). Widen "
        "target_min/target_max (the TCP reaches at most about 1.2 m from motor1's origin "
        "(0, 0, 0.714), above the table top z = 0.645 m; the default box is "
        "(-0.5, -0.25, 0.7) to (-0.2, 0.25, 0.9)) or target_spread_deg"
    )


def _check_reach(chain: _Chain, region: TargetRegion) -> None:
    """ValueError at once for a box that no pose can reach: below the table top, or
    farther from motor1's origin than the sum of the link offsets and the TCP offset."""
    m = chain.model
    if region.high[2] <= TABLE_TOP_Z:
        _empty(region, f"the box lies below the table top (z = {TABLE_TOP_Z} m)")
    origin = m.body_pos[chain.bodies[0]] + m.body_pos[chain.bodies[1]]  # base, motor1_link
    reach = sum(np.linalg.norm(m.body_pos[b]) for b in chain.bodies[2:])
    reach += np.linalg.norm(m.site_pos[chain.site])
    nearest = np.clip(origin, region.low, region.high)
    if np.linalg.norm(nearest - origin) > reach:
        _empty(
            region,
            f"the box is {np.linalg.norm(nearest - origin):.2f} m from motor1's origin, "
            f"beyond the arm's reach of {reach:.2f} m",
        )


def balance_weights(pos: np.ndarray, region: TargetRegion, grid: int = GRID) -> np.ndarray:
    """(M,) probabilities 1 / (candidates in the same cell), normalised: every reachable
    cell of a grid x grid x grid division of the box is about equally likely."""
    low, high = np.asarray(region.low), np.asarray(region.high)
    cell = np.clip(((pos - low) / (high - low) * grid).astype(int), 0, grid - 1)
    flat = np.ravel_multi_index(cell.T, (grid,) * 3)
    counts = np.bincount(flat, minlength=grid**3)
    weights = 1.0 / counts[flat]
    return weights / weights.sum()


def training_table(model: mujoco.MjModel, region: TargetRegion, size: int, seed: int) -> PoseTable:
    """`size` poses drawn with replacement (balanced over the box) from up to
    CANDIDATES_PER_POSE * size distinct candidates of the training stream."""
    pool = candidates(model, region, CANDIDATES_PER_POSE * size, seed, TRAIN_STREAM)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(TRAIN_STREAM, 1)))
    return pool.take(rng.choice(len(pool), size, p=balance_weights(pool.pos, region)))


def evaluation_poses(
    model: mujoco.MjModel, region: TargetRegion, size: int, seed: int
) -> PoseTable:
    """`size` distinct poses of the evaluation stream (independent of every training
    table), balanced over the box. ValueError if the region holds fewer."""
    pool = candidates(model, region, CANDIDATES_PER_POSE * size, seed, EVAL_STREAM)
    if len(pool) < size:
        raise ValueError(
            f"only {len(pool)} distinct evaluation poses found in the region "
            f"({region.describe()}); ask for fewer episodes or widen the region"
        )
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(EVAL_STREAM, 1)))
    idx = rng.choice(len(pool), size, replace=False, p=balance_weights(pool.pos, region))
    return pool.take(np.sort(idx))
