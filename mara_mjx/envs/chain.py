"""Forward kinematics of the MARA chain in plain jnp, and the TCP's geometric Jacobian.

MJX stays the model and the reference (`Arm.pose`, tests/test_chain.py checks this module
against `mjx.kinematics` and C MuJoCo): this is the same serial-chain recursion as
MuJoCo's `mj_kinematics` for a tree of bodies with one hinge each, written out for the
six bodies of the arm so that code outside the env (the reward-landscape analysis of
benchmarks/orientation_landscape.py) can use the arm's kinematics at a few hundred FLOPs per
configuration, without building an `mjx.Data`.

For body i with parent p, offset (pos_i, quat_i) in p's frame and hinge axis a_i at
anchor j_i in its own frame (MuJoCo's body_pos, body_quat, jnt_axis, jnt_pos):

    R_i' = R_p R(quat_i)                  orientation before the joint turns
    xaxis_i   = R_i' a_i                  joint axis, world frame
    xanchor_i = x_p + R_p pos_i + R_i' j_i
    R_i = R_i' Rot(a_i, q_i)              (Rodrigues)
    x_i = xanchor_i - R_i j_i             body origin, world frame

The TCP is the site `tcp` on the flange body `motor6_link`: p_tcp = x_6 + R_6 s. Its
geometric Jacobian (6, 6) in the world frame stacks J_pos (column i: xaxis_i x (p_tcp -
xanchor_i), m/rad, exactly as `Arm._pose` computes it) over J_rot (column i: xaxis_i,
rad/rad).

    chain = Chain.from_model(mj_model)      # e.g. mara_mjx.envs.arm.load_model()
    tcp_pos, tcp_quat = chain.tcp(q)        # (3,) m, (4,) (w, x, y, z) with w >= 0
    jac = chain.jacobian(q)                 # (6, 6): [J_pos; J_rot]
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import mujoco
import numpy as np

from mara_mjx.envs.geometry import quat_canonical, quat_to_mat_np


def _rodrigues(axis: jnp.ndarray, angle: jnp.ndarray) -> jnp.ndarray:
    """(3, 3) rotation by `angle` rad about the unit `axis` (3,)."""
    x, y, z = axis[0], axis[1], axis[2]
    c, s = jnp.cos(angle), jnp.sin(angle)
    t = 1.0 - c
    return jnp.array(
        [
            [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
        ]
    )


def _mat_to_quat(m: jnp.ndarray) -> jnp.ndarray:
    """(3, 3) rotation -> (w, x, y, z), branch-free (Shepperd's method: the largest of the
    four diagonal combinations picks the well-conditioned formula)."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    cands = jnp.stack(
        [
            jnp.array([1.0 + tr, m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]),
            jnp.array(
                [
                    m[2, 1] - m[1, 2],
                    1.0 + m[0, 0] - m[1, 1] - m[2, 2],
                    m[0, 1] + m[1, 0],
                    m[0, 2] + m[2, 0],
                ]
            ),
            jnp.array(
                [
                    m[0, 2] - m[2, 0],
                    m[0, 1] + m[1, 0],
                    1.0 - m[0, 0] + m[1, 1] - m[2, 2],
                    m[1, 2] + m[2, 1],
                ]
            ),
            jnp.array(
                [
                    m[1, 0] - m[0, 1],
                    m[0, 2] + m[2, 0],
                    m[1, 2] + m[2, 1],
                    1.0 - m[0, 0] - m[1, 1] + m[2, 2],
                ]
            ),
        ]
    )
    pick = jnp.argmax(jnp.array([tr, m[0, 0], m[1, 1], m[2, 2]]))
    # a one-hot select, not cands[pick]: jax2onnx lowers that batched gather (under vmap)
    # to a GatherND of the wrong rank; the sum adds exact zeros, so the result is the same
    quat = jnp.sum(jnp.where((jnp.arange(4) == pick)[:, None], cands, 0.0), axis=0)
    return quat / jnp.linalg.norm(quat)


@dataclasses.dataclass(frozen=True)
class Chain:
    """Constants of the six-hinge chain from base to flange (numpy, resolved once)."""

    base_pos: np.ndarray  # (3,) world position of the chain's root body (base)
    base_rot: np.ndarray  # (3, 3) its world orientation
    body_pos: np.ndarray  # (6, 3) offset of each moving body in its parent's frame
    body_rot: np.ndarray  # (6, 3, 3) orientation offset in its parent's frame
    axis: np.ndarray  # (6, 3) unit hinge axis, body frame
    anchor: np.ndarray  # (6, 3) hinge anchor, body frame
    site: np.ndarray  # (3,) the TCP site in the flange body's frame
    body_ids: tuple[int, ...] = ()  # MuJoCo ids of the six moving bodies, base to flange

    @classmethod
    def from_model(cls, m: mujoco.MjModel, site: str = "tcp") -> Chain:
        """The chain that ends at `site`'s body: every body on the path from its first
        jointed ancestor must carry exactly one hinge (ValueError otherwise), and the
        site's body must be the last of them."""
        bodies = []
        b = int(m.site(site).bodyid[0])
        while b > 0 and m.body_jntnum[b] > 0:
            if m.body_jntnum[b] != 1 or m.jnt_type[m.body_jntadr[b]] != mujoco.mjtJoint.mjJNT_HINGE:
                raise ValueError(f"body {m.body(b).name!r} must have exactly one hinge joint")
            bodies.append(b)
            b = int(m.body_parentid[b])
        bodies.reverse()
        if len(bodies) != 6:
            raise ValueError(f"expected a chain of 6 hinges to site {site!r}, got {len(bodies)}")
        root = int(m.body_parentid[bodies[0]])
        # The root is fixed (no joints above it): its world pose from MuJoCo's forward pass.
        d = mujoco.MjData(m)
        mujoco.mj_kinematics(m, d)
        jnt = [int(m.body_jntadr[b]) for b in bodies]
        return cls(
            base_pos=d.xpos[root].copy(),
            base_rot=d.xmat[root].reshape(3, 3).copy(),
            body_pos=np.stack([m.body_pos[b] for b in bodies]),
            body_rot=np.stack([quat_to_mat_np(m.body_quat[b]) for b in bodies]),
            axis=np.stack([m.jnt_axis[j] / np.linalg.norm(m.jnt_axis[j]) for j in jnt]),
            anchor=np.stack([m.jnt_pos[j] for j in jnt]),
            site=m.site_pos[m.site(site).id].copy(),
            body_ids=tuple(bodies),
        )

    def body_frames(self, q: jnp.ndarray):
        """q (6,) rad -> each moving body's origin (6, 3) and rotation (6, 3, 3), the joint
        axes xaxis (6, 3) and anchors xanchor (6, 3), world frame."""
        x = jnp.asarray(self.base_pos, jnp.float32)
        rot = jnp.asarray(self.base_rot, jnp.float32)
        xs, rots, axes, anchors = [], [], [], []
        for i in range(6):
            rot_pre = rot @ jnp.asarray(self.body_rot[i], jnp.float32)
            axis_w = rot_pre @ jnp.asarray(self.axis[i], jnp.float32)
            anchor_w = x + rot @ jnp.asarray(self.body_pos[i], jnp.float32)
            anchor_w = anchor_w + rot_pre @ jnp.asarray(self.anchor[i], jnp.float32)
            rot = rot_pre @ _rodrigues(jnp.asarray(self.axis[i], jnp.float32), q[i])
            x = anchor_w - rot @ jnp.asarray(self.anchor[i], jnp.float32)
            xs.append(x)
            rots.append(rot)
            axes.append(axis_w)
            anchors.append(anchor_w)
        return jnp.stack(xs), jnp.stack(rots), jnp.stack(axes), jnp.stack(anchors)

    def frames(self, q: jnp.ndarray):
        """q (6,) rad -> (flange origin (3,), flange rotation (3, 3), xaxis (6, 3),
        xanchor (6, 3)), world frame."""
        xs, rots, axes, anchors = self.body_frames(q)
        return xs[-1], rots[-1], axes, anchors

    def tcp(self, q: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
        """q (6,) -> TCP position (3,) m and flange orientation (4,) (w, x, y, z), w >= 0,
        world frame (as `Arm.pose`'s tcp_pos and tcp_quat)."""
        x, rot, _, _ = self.frames(q)
        return x + rot @ jnp.asarray(self.site, jnp.float32), quat_canonical(_mat_to_quat(rot))

    def jacobian(self, q: jnp.ndarray) -> jnp.ndarray:
        """q (6,) -> (6, 6) geometric Jacobian of the TCP, world frame: rows 0-2 d p_tcp / d q
        (m/rad), rows 3-5 the angular velocity per joint velocity (rad/rad)."""
        x, rot, axes, anchors = self.frames(q)
        tcp = x + rot @ jnp.asarray(self.site, jnp.float32)
        j_pos = jnp.cross(axes, tcp[None, :] - anchors).T
        return jnp.concatenate([j_pos, axes.T], axis=0)
