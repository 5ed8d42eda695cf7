"""The deployed IK finish (PolicyConfig.ik_finish) in numpy, for exported policies.

`python -m mara_mjx.export` writes the nominal arm's chain (mara_mjx/envs/chain.py: base
pose, body offsets, hinge axes and anchors, the TCP site) and mara_mjx/envs/task_space.py's
constants into an .npz policy's meta (`finish_meta`); numpy_policy.NumpyPolicy then runs
the same last approach as the JAX policy (`NumpyFinish`): a learnt step that would jump
into the finish zone is cut to just inside its edge (task_space.stop_outside), and within
the zone the step is the position-only damped-least-squares IK step, first toward 1 cm
short of the target (task_space.finish_step). Float64 here, float32 in JAX: equal to
float tolerance (tests/test_export_plots.py), except where a bisection step lands within
rounding of the zone's edge. `NumpyFinish.frames` (the chain's forward kinematics) and
`quat_mul` are the robot-side runner's too (runner.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np

CHAIN_FIELDS = ("base_pos", "base_rot", "body_pos", "body_rot", "axis", "anchor", "site")


def finish_meta(radius: float) -> dict[str, Any]:
    """The JSON-able description of the IK finish of `radius` (m) that NumpyFinish runs."""
    from mara_mjx.envs import task_space as ts

    chain = ts.nominal_chain()
    lower, upper = ts.joint_ranges()
    return {
        "radius": float(radius),
        "hold": ts.FINISH_HOLD,
        "within": ts.FINISH_WITHIN,
        "damping": ts.DAMPING,
        "max_position_step": ts.MAX_POSITION_STEP,
        "max_step_joint": ts.MAX_STEP_JOINT,
        "iters": ts.STOP_OUTSIDE_ITERS,
        "limited": True,  # task_space.limited_step (files without it: the step before)
        "joint_lower": list(lower),
        "joint_upper": list(upper),
        "chain": {k: np.asarray(getattr(chain, k), np.float64).tolist() for k in CHAIN_FIELDS},
    }


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a (x) b of (..., 4) (w, x, y, z) quaternions: the numpy twin of
    mara_mjx/envs/geometry.py's (JAX there; this file imports numpy only)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def _rodrigues(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations by `angle` (...) about the unit `axis` (3,)."""
    x, y, z = axis
    c, s = np.cos(angle), np.sin(angle)
    t = 1.0 - c
    rows = [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
    return np.stack([np.stack(r, -1) for r in rows], -2)


class NumpyFinish:
    """finish_meta's description, run on batches: `NumpyFinish(meta)(q, e, delta)` ->
    the joint displacement (..., 6) the deployed JAX policy would take."""

    def __init__(self, meta: dict[str, Any]):
        self.meta = meta
        self.chain = {k: np.asarray(meta["chain"][k], np.float64) for k in CHAIN_FIELDS}
        self.lower = np.asarray(meta["joint_lower"], np.float64)
        self.upper = np.asarray(meta["joint_upper"], np.float64)

    def frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q (..., 6) -> TCP position (..., 3), hinge axes (..., 6, 3) and anchors
        (..., 6, 3), world frame (envs/chain.py's recursion)."""
        c = self.chain
        x = np.broadcast_to(c["base_pos"], q.shape[:-1] + (3,))
        rot = np.broadcast_to(c["base_rot"], q.shape[:-1] + (3, 3))
        axes, anchors = [], []
        for i in range(6):
            pre = rot @ c["body_rot"][i]
            axes.append(pre @ c["axis"][i])
            anchor = x + rot @ c["body_pos"][i] + pre @ c["anchor"][i]
            anchors.append(anchor)
            rot = pre @ _rodrigues(c["axis"][i], q[..., i])
            x = anchor - rot @ c["anchor"][i]
        return x + rot @ c["site"], np.stack(axes, -2), np.stack(anchors, -2)

    def tcp(self, q: np.ndarray) -> np.ndarray:
        return self.frames(q)[0]

    def pose_step(self, q: np.ndarray, e: np.ndarray) -> np.ndarray:
        """task_space.pose_step without an orientation: (..., 6) rad."""
        jac, dx = self._position_rows(q, e)
        return self._joint_capped(self._dls(jac, dx))

    def _position_rows(self, q: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The position Jacobian (..., 3, 6) at q and the asked TCP move (..., 3): -e, at
        most max_position_step long."""
        tcp, axes, anchors = self.frames(q)
        jac = np.swapaxes(np.cross(axes, tcp[..., None, :] - anchors), -1, -2)  # (..., 3, 6)
        norm = np.linalg.norm(e, axis=-1, keepdims=True)
        return jac, -e * np.minimum(1.0, self.meta["max_position_step"] / np.maximum(norm, 1e-12))

    def _dls(self, jac: np.ndarray, dx: np.ndarray) -> np.ndarray:
        """task_space.dls_step: J^T (J J^T + damping^2 I)^-1 dx, batched."""
        gram = jac @ np.swapaxes(jac, -1, -2) + self.meta["damping"] ** 2 * np.eye(3)
        return (np.swapaxes(jac, -1, -2) @ np.linalg.solve(gram, dx[..., None]))[..., 0]

    def _joint_capped(self, dq: np.ndarray) -> np.ndarray:
        """dq scaled down whole so that no joint moves more than max_step_joint."""
        big = np.max(np.abs(dq), axis=-1, keepdims=True)
        return dq * np.minimum(1.0, self.meta["max_step_joint"] / np.maximum(big, 1e-12))

    def finish_step(self, q: np.ndarray, e: np.ndarray) -> np.ndarray:
        """task_space.finish_step: toward `hold` short of the target, then onto it; with
        the meta's "limited" (files exported since NOTES section 52) the step respects the
        joint limits (task_space.limited_step), else it is the plain step the file's
        policy was exported with."""
        hold = self.meta["hold"]
        dist = np.linalg.norm(e, axis=-1, keepdims=True)
        short = e * (1.0 - hold / np.maximum(dist, 1e-12))
        aim = np.where(dist > self.meta["within"] * hold, short, e)
        return self.limited_step(q, aim) if self.meta.get("limited") else self.pose_step(q, aim)

    def limited_step(self, q: np.ndarray, e: np.ndarray) -> np.ndarray:
        """task_space.limited_step: the joints the step would take past a limit stop at
        it, the others solved again for the rest; scaled as pose_step."""
        jac, dx = self._position_rows(q, e)
        d = self._joint_capped(self._dls(jac, dx))  # pose_step's step
        over = (q + d > self.upper) | (q + d < self.lower)
        pinned = np.where(over, np.clip(q + d, self.lower, self.upper) - q, 0.0)
        free = self._dls(
            np.where(over[..., None, :], 0.0, jac), dx - (jac @ pinned[..., None])[..., 0]
        )
        return self._joint_capped(np.where(over, pinned, free))

    def stop_outside(self, q: np.ndarray, e: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """task_space.stop_outside with the finish's radius."""
        r2 = self.meta["radius"] ** 2
        target = self.tcp(q) - e

        def outside(alpha: np.ndarray) -> np.ndarray:
            after = self.tcp(np.clip(q + alpha[..., None] * dq, self.lower, self.upper))
            return np.sum(np.square(after - target), -1) >= r2

        shape = q.shape[:-1]
        jumps = (np.sum(np.square(e), -1) >= r2) & ~outside(np.ones(shape))
        lo, hi = np.zeros(shape), np.ones(shape)
        for _ in range(int(self.meta["iters"])):
            mid = 0.5 * (lo + hi)
            out = outside(mid)
            lo, hi = np.where(out, mid, lo), np.where(out, hi, mid)
        return np.where(jumps, hi, 1.0)[..., None] * dq

    def __call__(self, q: np.ndarray, e: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """The learnt joint displacement `delta` (..., 6) at joints q, TCP error e ->
        the deployed displacement (the networks' ik_finish branch)."""
        near = np.sum(np.square(e), -1, keepdims=True) < self.meta["radius"] ** 2
        return np.where(near, self.finish_step(q, e), self.stop_outside(q, e, delta))
