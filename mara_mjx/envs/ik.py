"""Host-side inverse kinematics (C MuJoCo, numpy): is a target inside the workspace?

Used at construction to reject targets no policy could reach (spec section 3), and
by the tests to show the spec's target pose is reachable inside the joint limits.
Damped least squares from several seeds, clipped to the joint box every
iteration; a solution counts only if it does not collide.
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

# A seed near the spec's example solution of the default target pose.
_SPEC_SEED = np.array([1.3338, -1.5341, -0.7833, 0.0, 2.3903, -0.237])


class IKResult(NamedTuple):
    q: np.ndarray  # (6,) rad, inside the joint limits
    position_error: float  # m, Euclidean
    angle_error: float  # rad (0 if orientation was not asked for)
    collided: bool


def _quat_err_vec(q_tcp: np.ndarray, q_target: np.ndarray) -> np.ndarray:
    """Rotation vector (world frame) taking the target orientation to the TCP's."""
    err = np.empty(4)
    conj = np.empty(4)
    mujoco.mju_negQuat(conj, q_target)
    mujoco.mju_mulQuat(err, q_tcp, conj)
    if err[0] < 0:
        err = -err
    vec = np.empty(3)
    mujoco.mju_quat2Vel(vec, err, 1.0)
    return vec


def solve(
    model: mujoco.MjModel,
    target_pos: np.ndarray,
    target_quat: np.ndarray | None = None,
    *,
    seeds: int = 16,
    iterations: int = 200,
    seed: int = 0,
) -> IKResult:
    """Best collision-free IK solution over `seeds` starts (the first is the spec's)."""
    data = mujoco.MjData(model)
    site = model.site("tcp").id
    flange = model.body("motor6_link").id
    lower, upper = model.jnt_range[:, 0], model.jnt_range[:, 1]
    rng = np.random.default_rng(seed)
    starts = [_SPEC_SEED, np.zeros(6)] + [rng.uniform(lower, upper) for _ in range(seeds - 2)]
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    best: IKResult | None = None
    for q in starts:
        q = np.clip(np.array(q, float), lower, upper)
        for _ in range(iterations):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            err = target_pos - data.site_xpos[site]
            mujoco.mj_jacSite(model, data, jacp, jacr, site)
            if target_quat is None:
                jac, e = jacp, err
            else:
                rot = -_quat_err_vec(data.xquat[flange], target_quat)
                jac, e = np.vstack([jacp, jacr]), np.concatenate([err, 0.3 * rot])
            step = jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(len(e)), e)
            q = np.clip(q + step, lower, upper)
            if np.linalg.norm(e) < 1e-7:
                break
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        collided = bool(np.any(data.contact.dist[: data.ncon] < 0)) if data.ncon else False
        pos_err = float(np.linalg.norm(target_pos - data.site_xpos[site]))
        ang = 0.0
        if target_quat is not None:
            ang = float(np.linalg.norm(_quat_err_vec(data.xquat[flange], target_quat)))
        result = IKResult(q, pos_err, ang, collided)
        if best is None or (best.collided, best.position_error + 0.1 * best.angle_error) > (
            collided,
            pos_err + 0.1 * ang,
        ):
            best = result
        if not collided and pos_err < 1e-4 and ang < 1e-3:
            break
    assert best is not None
    return best


def check_reachable(
    model: mujoco.MjModel,
    target_pos: np.ndarray,
    target_quat: np.ndarray | None,
    *,
    position_tol: float = 1e-3,
    angle_tol: float = np.deg2rad(1.0),
) -> IKResult:
    """Raise ValueError unless some collision-free pose inside the joint limits reaches the
    target (position, and orientation if given) within the tolerances."""
    res = solve(model, np.asarray(target_pos, float), target_quat)
    if res.collided or res.position_error > position_tol or res.angle_error > angle_tol:
        what = "position" if target_quat is None else "pose"
        raise ValueError(
            f"target {what} {np.round(target_pos, 4).tolist()}"
            + ("" if target_quat is None else f" quat {np.round(target_quat, 4).tolist()}")
            + " is outside the arm's workspace: the best collision-free joint solution inside "
            f"the limits misses it by {res.position_error * 1000:.1f} mm"
            + ("" if target_quat is None else f" and {np.rad2deg(res.angle_error):.1f} deg")
            + (" (and collides)" if res.collided else "")
            + ". Choose a target above the table (z > 0.645 m) within about 0.9 m of the "
            "shoulder (0.118, 0, 0.877)."
        )
    return res
