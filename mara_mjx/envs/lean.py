"""A lean pose-and-collision pass for the train driver: the chain's kinematics and the 24
contact pairs' distances in plain jnp (issue 14). MJX stays the model and the reference.

The train driver needs, per step, the TCP pose, its positional Jacobian and one bit: does
any listed contact pair penetrate. Through MJX that is `mjx.kinematics` (every body,
geom and site of the model) and `mjx.collision` (a contact manifold per pair: points,
frames, several candidates for capsule-box), about 60 kFLOP and 65 kB of XLA traffic per
step (benchmarks/NOTES.md section 1). Here it is what the bit needs:

* kinematics: `mara_mjx.envs.chain` (six hinge transforms);
* each pair's signed distance, MuJoCo's convention (negative when penetrating), with
  every geom of a pair a capsule (segment + radius) or a box fixed in the world (the
  table and the base; checked at construction):
  - capsule-capsule: the closest points of the two segments (Ericson, "Real-Time
    Collision Detection", 5.1.9), distance minus both radii;
  - capsule-box: in the box's frame the squared distance of a point p(t) = a + t (b - a)
    of the segment to the box is f(t) = sum_i max(0, |p_i(t)| - h_i)^2, convex,
    continuously differentiable and piecewise quadratic in t with breaks where
    p_i(t) = +-h_i. So f' is nondecreasing and linear between breaks: the largest knot
    (breaks, 0 and 1) where f' <= 0 and the smallest where f' >= 0 bound one piece, and
    f' = 0 at the linear interpolation between them, the exact minimiser over [0, 1]
    (branch-free, no sort): distance = sqrt(min f) minus the radius, and -radius when
    the segment enters the box (f = 0).
* collided = any distance < 0, as `Arm.pose` (any MJX contact with dist < 0).

Exact distances rather than MJX's contact manifolds, so near contact the bit can differ
from MJX's where MJX's capsule-box manifold is itself approximate;
`benchmarks/lean_check.py` counts such configurations against MJX and C MuJoCo.

    lean = LeanArm.from_model(arm.mj_model)
    pose = lean.pose(q)        # ArmPose, as Arm.pose(q)
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mara_mjx.envs.chain import Chain, _mat_to_quat
from mara_mjx.envs.geometry import quat_canonical, quat_to_mat_np
from mara_mjx.envs.pose import ArmPose

_CAPSULE, _BOX = int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_BOX)


@dataclasses.dataclass(frozen=True)
class LeanArm:
    """Chain constants plus each contact pair's geometry (numpy, resolved once)."""

    chain: Chain
    # capsule-capsule pairs: chain body index (0-5) of each capsule, local centre (3,),
    # local axis (3,) (unit), half-length, radius
    cc_body: np.ndarray  # (P, 2) int
    cc_pos: np.ndarray  # (P, 2, 3)
    cc_axis: np.ndarray  # (P, 2, 3)
    cc_half: np.ndarray  # (P, 2)
    cc_radius: np.ndarray  # (P, 2)
    # capsule-box pairs: the capsule as above, the box's world centre, rotation, half sizes
    cb_body: np.ndarray  # (Q,) int
    cb_pos: np.ndarray  # (Q, 3)
    cb_axis: np.ndarray  # (Q, 3)
    cb_half: np.ndarray  # (Q,)
    cb_radius: np.ndarray  # (Q,)
    box_pos: np.ndarray  # (Q, 3)
    box_rot: np.ndarray  # (Q, 3, 3)
    box_half: np.ndarray  # (Q, 3)

    @classmethod
    def from_model(cls, m: mujoco.MjModel) -> LeanArm:
        """The lean pass of `m`'s explicit <pair>s; ValueError for a pair it does not cover
        (a geom other than a capsule or a world-fixed box, a margin or gap)."""
        chain = Chain.from_model(m)
        index = {b: i for i, b in enumerate(chain.body_ids)}
        d = mujoco.MjData(m)
        mujoco.mj_kinematics(m, d)

        def capsule(g: int):
            body = int(m.geom_bodyid[g])
            if body not in index:
                raise ValueError(f"capsule {m.geom(g).name!r} is not on the arm's chain")
            axis = quat_to_mat_np(m.geom_quat[g])[:, 2]
            return index[body], m.geom_pos[g].copy(), axis, m.geom_size[g][1], m.geom_size[g][0]

        cc, cb = [], []
        for p in range(m.npair):
            g1, g2 = int(m.pair_geom1[p]), int(m.pair_geom2[p])
            if m.pair_margin[p] != 0 or m.pair_gap[p] != 0:
                raise ValueError(f"pair {p}: a margin or gap is not supported by the lean pass")
            types = (int(m.geom_type[g1]), int(m.geom_type[g2]))
            if types == (_CAPSULE, _CAPSULE):
                cc.append((capsule(g1), capsule(g2)))
            elif _BOX in types and _CAPSULE in types:
                box, cap = (g1, g2) if types[0] == _BOX else (g2, g1)
                if int(m.geom_bodyid[box]) in index:
                    raise ValueError(f"box {m.geom(box).name!r} moves with the arm")
                cb.append((capsule(cap), (d.geom_xpos[box], d.geom_xmat[box], m.geom_size[box])))
            else:
                names = (m.geom(g1).name, m.geom(g2).name)
                raise ValueError(f"pair {names}: only capsule-capsule and capsule-box pairs")

        def stack(rows, k):
            return np.array([r[k] for r in rows], dtype=np.float64)

        cc1, cc2 = [c[0] for c in cc], [c[1] for c in cc]
        caps = [c[0] for c in cb]
        return cls(
            chain=chain,
            cc_body=np.array([[a[0], b[0]] for a, b in zip(cc1, cc2, strict=True)], np.int32),
            cc_pos=np.stack([stack(cc1, 1), stack(cc2, 1)], axis=1),
            cc_axis=np.stack([stack(cc1, 2), stack(cc2, 2)], axis=1),
            cc_half=np.stack([stack(cc1, 3), stack(cc2, 3)], axis=1),
            cc_radius=np.stack([stack(cc1, 4), stack(cc2, 4)], axis=1),
            cb_body=np.array([c[0] for c in caps], np.int32),
            cb_pos=stack(caps, 1),
            cb_axis=stack(caps, 2),
            cb_half=stack(caps, 3),
            cb_radius=stack(caps, 4),
            box_pos=np.array([c[1][0] for c in cb]),
            box_rot=np.array([np.asarray(c[1][1]).reshape(3, 3) for c in cb]),
            box_half=np.array([c[1][2] for c in cb]),
        )

    # ------------------------------------------------------------------ distances
    def distances(self, q: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Signed distances (m) of the capsule-capsule (P,) and capsule-box (Q,) pairs at
        joint positions q (6,)."""
        xs, rots, _, _ = self.chain.body_frames(q)
        return self._distances(xs, rots)

    def _distances(self, xs: jax.Array, rots: jax.Array) -> tuple[jax.Array, jax.Array]:
        f32 = jnp.float32

        def segment(body, pos, axis, half):
            """World endpoints of capsule segments on chain bodies `body`."""
            centre = xs[body] + jnp.einsum("...ij,...j->...i", rots[body], jnp.asarray(pos, f32))
            direction = jnp.einsum("...ij,...j->...i", rots[body], jnp.asarray(axis, f32))
            offset = direction * jnp.asarray(half, f32)[..., None]
            return centre - offset, centre + offset

        a0, a1 = segment(
            self.cc_body[:, 0], self.cc_pos[:, 0], self.cc_axis[:, 0], self.cc_half[:, 0]
        )
        b0, b1 = segment(
            self.cc_body[:, 1], self.cc_pos[:, 1], self.cc_axis[:, 1], self.cc_half[:, 1]
        )
        cc = jax.vmap(segment_segment_distance)(a0, a1, b0, b1)
        cc = cc - jnp.asarray(self.cc_radius.sum(axis=1), f32)

        c0, c1 = segment(self.cb_body, self.cb_pos, self.cb_axis, self.cb_half)
        rot_t = jnp.asarray(np.swapaxes(self.box_rot, 1, 2), f32)
        box_pos = jnp.asarray(self.box_pos, f32)
        local0 = jnp.einsum("qij,qj->qi", rot_t, c0 - box_pos)
        local1 = jnp.einsum("qij,qj->qi", rot_t, c1 - box_pos)
        cb = jax.vmap(segment_box_distance)(local0, local1, jnp.asarray(self.box_half, f32))
        return cc, cb - jnp.asarray(self.cb_radius, f32)

    # ------------------------------------------------------------------- the pose
    def pose(self, q: jax.Array, collide: bool = True) -> ArmPose:
        """`Arm.pose(q, collide)` without MJX: TCP position, flange quaternion (w >= 0),
        positional Jacobian, and whether any pair penetrates."""
        with jax.named_scope("lean_kinematics"):
            xs, rots, axes, anchors = self.chain.body_frames(q)
            tcp = xs[-1] + rots[-1] @ jnp.asarray(self.chain.site, jnp.float32)
            quat = quat_canonical(_mat_to_quat(rots[-1]))
            jac = jnp.cross(axes, tcp[None, :] - anchors).T
        if not collide:
            return ArmPose(tcp, quat, jac, jnp.array(False))
        with jax.named_scope("lean_collision"):
            cc, cb = self._distances(xs, rots)
            collided = jnp.any(cc < 0.0) | jnp.any(cb < 0.0)
        return ArmPose(tcp, quat, jac, collided)


def segment_segment_distance(p1, q1, p2, q2) -> jax.Array:
    """Distance (m) between segments [p1, q1] and [p2, q2] (each (3,)), branch-free
    (Ericson 5.1.9, with the degenerate cases clamped)."""
    eps = 1e-12
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    # sums of products, not jnp.dot: jax2onnx lowers a vector dot under vmap wrongly
    # (the deployed collision guard, envs/clearance.py, is exported through here)
    a, e, f = jnp.sum(d1 * d1), jnp.sum(d2 * d2), jnp.sum(d2 * r)
    c, b = jnp.sum(d1 * r), jnp.sum(d1 * d2)
    denom = a * e - b * b
    s = jnp.where(denom > eps, jnp.clip((b * f - c * e) / jnp.maximum(denom, eps), 0.0, 1.0), 0.0)
    t = (b * s + f) / jnp.maximum(e, eps)
    # t outside [0, 1]: clamp it and recompute s for the clamped t
    s = jnp.where(t < 0.0, jnp.clip(-c / jnp.maximum(a, eps), 0.0, 1.0), s)
    s = jnp.where(t > 1.0, jnp.clip((b - c) / jnp.maximum(a, eps), 0.0, 1.0), s)
    t = jnp.clip(t, 0.0, 1.0)
    return jnp.linalg.norm((p1 + d1 * s) - (p2 + d2 * t))


def segment_box_distance(a, b, half) -> jax.Array:
    """Distance (m) from segment [a, b] to the box |x_i| <= half_i (all in the box's
    frame); 0 when they intersect. Exact: f(t) = sum_i max(0, |a_i + t d_i| - h_i)^2 is
    minimised where its nondecreasing, piecewise linear slope crosses 0."""
    d = b - a
    safe = jnp.where(jnp.abs(d) > 1e-12, d, 1e-12)
    breaks = jnp.concatenate([(half - a) / safe, (-half - a) / safe])
    # (0 and 1 shaped like a[:1], not a literal array: jax2onnx 0.17 mis-shaped a batched
    # literal inside an If, where the plan's restarts then checked their paths; kept for
    # their Loop; same values)
    ends = [jnp.zeros_like(a[:1]), jnp.ones_like(a[:1])]
    knots = jnp.clip(jnp.concatenate([*ends, breaks]), 0.0, 1.0)
    p = a + knots[:, None] * d
    slope = jnp.sum(jnp.maximum(jnp.abs(p) - half, 0.0) * jnp.sign(p) * d, axis=-1)  # f'/2
    down, up = slope <= 0.0, slope >= 0.0
    # f' <= 0 up to lo and >= 0 from hi on, and no knot lies strictly between them
    lo, hi = jnp.max(jnp.where(down, knots, 0.0)), jnp.min(jnp.where(up, knots, 1.0))
    slope_lo = jnp.max(jnp.where(down, slope, -jnp.inf))
    slope_hi = jnp.min(jnp.where(up, slope, jnp.inf))
    crossing = (hi > lo) & (slope_hi > slope_lo)
    rise = jnp.where(crossing, slope_hi - slope_lo, 1.0)
    t = jnp.where(crossing, lo - slope_lo * (hi - lo) / rise, lo)
    p = a + jnp.clip(t, lo, hi) * d
    return jnp.sqrt(jnp.sum(jnp.square(jnp.maximum(jnp.abs(p) - half, 0.0))))
