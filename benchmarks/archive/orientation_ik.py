"""Which arm configurations reach the orientation tasks' target pose? (orientation issue)

Damped least-squares IK (the same iteration as mara_mjx/envs/ik.py, clipped to the joint
box) from many random starts and from the configurations the trained policies settled
in (issue 11). Prints the distinct solution branches (position error, orientation error,
collided, joints at their limits) and, for each settled configuration, where a local
descent from it ends: a branch with the pose exact, or stuck at a joint limit with the
orientation off.

    python benchmarks/archive/orientation_ik.py [--starts 400] \
        [--out benchmarks/results/orientation_ik.json]
"""

from __future__ import annotations

import argparse
import json

import mujoco
import numpy as np

from mara_mjx.envs.arm import load_model
from mara_mjx.envs.ik import _quat_err_vec

TARGET_POS = np.array([-0.40028, 0.095615, 0.72466])
TARGET_QUAT = np.array([0.0, 0.7071068, 0.7071068, 0.0])

# Where the default-preset policies settled (issue 11; deterministic policy, 200 steps).
SETTLED = {
    "MARAOrient seed 0 (a)": [1.24, -2.35, -2.19, 0.14, 2.37, -0.12],
    "MARAOrient seed 0 (b)": [1.66, -2.35, -2.13, -0.50, 2.34, -0.25],
    "MARAOrient seed 2": [1.77, -2.35, -2.30, -0.66, 2.56, -0.69],
    "MARACollisionOrient seed 0": [-1.81, 1.76, 1.23, 3.14, 2.46, -0.18],
    "IK (issue)": [1.3338, -1.5333, -0.7816, 0.0, 2.3899, -0.237],
}


def descend(model, data, q, iterations=400, orient_weight=0.3):
    site = model.site("tcp").id
    flange = model.body("motor6_link").id
    lower, upper = model.jnt_range[:, 0], model.jnt_range[:, 1]
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    q = np.clip(np.array(q, float), lower, upper)
    for _ in range(iterations):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        err = TARGET_POS - data.site_xpos[site]
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        rot = -_quat_err_vec(data.xquat[flange], TARGET_QUAT)
        jac, e = np.vstack([jacp, jacr]), np.concatenate([err, orient_weight * rot])
        step = jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(6), e)
        q = np.clip(q + step, lower, upper)
    return q, measure(model, data, q)


def measure(model, data, q):
    site = model.site("tcp").id
    flange = model.body("motor6_link").id
    lower, upper = model.jnt_range[:, 0], model.jnt_range[:, 1]
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    mujoco.mj_collision(model, data)
    collided = bool(np.any(data.contact.dist[: data.ncon] < 0)) if data.ncon else False
    pos_err = TARGET_POS - data.site_xpos[site]
    rotvec = _quat_err_vec(data.xquat[flange], TARGET_QUAT)
    at_limit = [i + 1 for i in range(6) if min(q[i] - lower[i], upper[i] - q[i]) < 1e-3]
    return {
        "q": np.round(q, 4).tolist(),
        "position_error_mm": float(1000 * np.linalg.norm(pos_err)),
        "angle_deg": float(np.rad2deg(np.linalg.norm(rotvec))),
        "rotvec_deg": np.round(np.rad2deg(rotvec), 2).tolist(),
        "collided": collided,
        "joints_at_limit": at_limit,
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--starts", type=int, default=400)
    p.add_argument("--out", default="")
    args = p.parse_args()
    model = load_model()
    data = mujoco.MjData(model)
    lower, upper = model.jnt_range[:, 0], model.jnt_range[:, 1]
    rng = np.random.default_rng(0)
    ends = []
    for _ in range(args.starts):
        q, m = descend(model, data, rng.uniform(lower, upper))
        ends.append(m)
    exact = [m for m in ends if m["position_error_mm"] < 0.1 and m["angle_deg"] < 0.1]
    # distinct branches: cluster exact solutions by joint vector (wrap joints 1, 4, 6 by 2 pi)
    branches = []
    for m in exact:
        q = np.array(m["q"])
        for b in branches:
            if np.max(np.abs(np.array(b["q"]) - q)) < 0.05:
                b["count"] += 1
                break
        else:
            branches.append({**m, "count": 1})
    print(
        f"{args.starts} random starts: {len(exact)} end on the exact pose; "
        f"{len(branches)} distinct branches:"
    )
    for b in sorted(branches, key=lambda b: -b["count"]):
        print(
            f"  n={b['count']:3d} q={b['q']} collided={b['collided']} limits={b['joints_at_limit']}"
        )
    stuck = [m for m in ends if m not in exact]
    angles = np.array([m["angle_deg"] for m in stuck])
    pos_ok = np.array([m["position_error_mm"] < 0.5 for m in stuck])
    print(
        f"{len(stuck)} starts end elsewhere; of them {pos_ok.sum()} with position < 0.5 mm, "
        "their orientation error: median "
        f"{np.median(angles[pos_ok]) if pos_ok.any() else 0:.1f} deg"
    )
    settled = {}
    for name, q in SETTLED.items():
        here = measure(model, data, np.array(q))
        q_end, there = descend(model, data, np.array(q))
        settled[name] = {"at": here, "local_descent_ends": there}
        print(
            f"{name}: at q: pos {here['position_error_mm']:.1f} mm, "
            f"angle {here['angle_deg']:.1f} deg "
            f"{here['rotvec_deg']}, collided {here['collided']}, limits {here['joints_at_limit']}"
        )
        print(
            f"    local descent -> pos {there['position_error_mm']:.2f} mm, "
            f"angle {there['angle_deg']:.2f} deg, "
            f"q {there['q']}, collided {there['collided']}, limits {there['joints_at_limit']}"
        )
    if args.out:
        with open(args.out, "w") as f:
            json.dump(
                {
                    "starts": args.starts,
                    "branches": branches,
                    "settled": settled,
                    "stuck_angles_deg": angles.tolist(),
                },
                f,
                indent=1,
            )


if __name__ == "__main__":
    main()
