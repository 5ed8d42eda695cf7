"""The lean train-driver pass (mara_mjx/envs/lean.py) against MJX and C MuJoCo, and its speed.

    python benchmarks/lean_check.py check --random 100000 --near 100000 --out lean_check.json
    python benchmarks/lean_check.py check --kinematics fused --out fused_check.json
    python benchmarks/lean_check.py time --envs 65536 --steps 100      # on a GPU

`check`: the pass `--kinematics` names, the lean pass ('lean', as `LeanArm.pose`) or its
scalar form ('fused', `fused_pose.arm_pose`; the JSON's keys then say `fused_` where they
say `lean_`), on random configurations inside the joint limits, and near-contact ones
(bisection along the segment from a free to a colliding configuration, by the pass's own flag,
to 1e-7 of its length, then a random joint offset of up to `--offset` rad). For each:
TCP position, flange quaternion and positional Jacobian against `mjx.kinematics`; the
collided flag of the lean pass, of MJX (`Arm.pose`) and of C MuJoCo (`mj_collision`, any
contact with dist < 0), and C MuJoCo's smallest signed pair distance (`mj_geomDistance`
over the 24 pairs), by which the flag disagreements are binned: within float32 precision
of contact (|d| < 1e-6 m) two correct implementations may disagree. Where the lean pass
and C MuJoCo disagree, an independent float64 reference (dense sampling of each capsule
segment against each box) says which one is right: C MuJoCo's capsule-box test misses
some capsules that pass through the table or the base (found here: a capsule centred
inside the 5-cm table top, reported 4.2 mm away).

`time`: MARACollisionOrient's train-driver `env.step`, vmapped over `--envs` and scanned
over `--steps` (random actions), with kinematics='mjx' and 'lean': compile time, then the
median of 5 timed calls (env steps/s).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

BANDS = (0.0, 1e-6, 1e-5, 1e-4, np.inf)
COMMAND = "python benchmarks/lean_check.py"


def c_mujoco(m: mujoco.MjModel, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C MuJoCo's collided flag and smallest signed pair distance (m) per configuration."""
    d = mujoco.MjData(m)
    flags, dmin = np.zeros(len(qs), bool), np.zeros(len(qs))
    fromto = np.zeros(6)
    pairs = list(zip(m.pair_geom1, m.pair_geom2, strict=True))
    for i, q in enumerate(qs):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        flags[i] = any(d.contact[k].dist < 0 for k in range(d.ncon))
        dmin[i] = min(mujoco.mj_geomDistance(m, d, g1, g2, 1.0, fromto) for g1, g2 in pairs)
    return flags, dmin


def reference_flags(lean, qs: np.ndarray, samples: int = 20001) -> np.ndarray:
    """An independent float64 answer for the capsule-box pairs: the segment's distance to
    each box by dense sampling (error below the segment's length / samples), combined with
    the lean pass's capsule-capsule distances. Used to arbitrate where the lean pass and C
    MuJoCo disagree."""
    ts = np.linspace(0.0, 1.0, samples)[:, None]
    out = np.zeros(len(qs), bool)
    for i, q in enumerate(qs):
        xs, rots, _, _ = (np.asarray(x, np.float64) for x in lean.chain.body_frames(q))
        hit = False
        for k in range(len(lean.cb_body)):
            b = lean.cb_body[k]
            centre = xs[b] + rots[b] @ lean.cb_pos[k]
            axis = rots[b] @ lean.cb_axis[k]
            a0, a1 = centre - axis * lean.cb_half[k], centre + axis * lean.cb_half[k]
            pts = (a0 + ts * (a1 - a0) - lean.box_pos[k]) @ lean.box_rot[k]
            gap = np.sqrt(np.min(np.sum(np.maximum(np.abs(pts) - lean.box_half[k], 0) ** 2, 1)))
            hit |= gap - lean.cb_radius[k] < 0
        cc, _ = lean.distances(q)
        out[i] = hit or bool(np.any(np.asarray(cc) < 0))
    return out


def check(args) -> dict:
    from mara_mjx.envs.arm import Arm

    arm = Arm()
    lean = arm.lean
    k = args.kinematics
    tested = functools.partial(arm.pose_with, kinematics=k)
    mjx_pose = jax.jit(jax.vmap(arm.pose))
    tested_pose = jax.jit(jax.vmap(tested))
    tested_flag = jax.jit(jax.vmap(lambda q: tested(q).collided))
    rng = np.random.default_rng(args.seed)
    sets = {"random": rng.uniform(arm.lower, arm.upper, (args.random, 6)).astype(np.float32)}
    # near contact: pairs of a free and a colliding random configuration, bisected
    pool = rng.uniform(arm.lower, arm.upper, (4 * args.near, 6)).astype(np.float32)
    hit = np.asarray(tested_flag(pool))
    n = min(args.near, int(hit.sum()), int((~hit).sum()))
    lo, hi = pool[~hit][:n].astype(np.float64), pool[hit][:n].astype(np.float64)
    for _ in range(24):
        mid = (0.5 * (lo + hi)).astype(np.float32)
        f = np.asarray(tested_flag(mid))[:, None]
        hi, lo = np.where(f, mid, hi), np.where(f, lo, mid)
    near = 0.5 * (lo + hi) + rng.uniform(-args.offset, args.offset, (n, 6))
    sets["near_contact"] = np.clip(near, arm.lower, arm.upper).astype(np.float32)

    out = {"command": " ".join([COMMAND, *sys.argv[1:]]), "jax": jax.__version__,
           "mujoco": mujoco.__version__, "device": str(jax.devices()[0])}  # fmt: skip
    for name, qs in sets.items():
        a, b = mjx_pose(qs), tested_pose(qs)
        c_flag, c_dist = c_mujoco(arm.mj_model, qs)
        mjx_flag, tested_f = np.asarray(a.collided), np.asarray(b.collided)
        band = np.digitize(np.abs(c_dist), BANDS) - 1
        rows = {}
        for j in range(len(BANDS) - 1):
            sel = band == j
            rows[f"|d| {BANDS[j]:g}-{BANDS[j + 1]:g} m"] = {
                "configurations": int(sel.sum()),
                f"{k}_vs_c_mismatch": int((tested_f[sel] != c_flag[sel]).sum()),
                "mjx_vs_c_mismatch": int((mjx_flag[sel] != c_flag[sel]).sum()),
                f"{k}_vs_mjx_mismatch": int((tested_f[sel] != mjx_flag[sel]).sum()),
            }
        disagree = np.where(tested_f != c_flag)[0]
        ref = reference_flags(lean, qs[disagree])
        agree_ref = int((ref == tested_f[disagree]).sum())
        out[name] = {
            "configurations": len(qs),
            f"{k}_vs_c_disagreements": len(disagree),
            f"of_them_{k}_agrees_with_the_float64_reference": agree_ref,
            "of_them_c_says_free_where_the_reference_finds_penetration": int(
                (ref & ~c_flag[disagree]).sum()
            ),
            "collided_fraction_c": float(c_flag.mean()),
            "max_abs_error_vs_mjx": {
                "tcp_pos_m": float(np.abs(np.asarray(a.tcp_pos - b.tcp_pos)).max()),
                "tcp_quat": float(np.abs(np.asarray(a.tcp_quat - b.tcp_quat)).max()),
                "tcp_jac": float(np.abs(np.asarray(a.tcp_jac - b.tcp_jac)).max()),
            },
            "flags_by_c_distance": rows,
        }
        print(name, json.dumps(out[name], indent=1), flush=True)
    return out


def timing(args) -> dict:
    import mara_mjx

    out = {"command": " ".join([COMMAND, *sys.argv[1:]]), "jax": jax.__version__,
           "device": str(jax.devices()[0]), "envs": args.envs, "steps": args.steps}  # fmt: skip
    for kinematics in ("mjx", "lean"):
        env = mara_mjx.make("MARACollisionOrient", kinematics=kinematics)
        keys = jax.random.split(jax.random.key(0), args.envs)
        state = jax.jit(jax.vmap(env.reset))(keys)
        lower, upper = jnp.asarray(env.joint_lower), jnp.asarray(env.joint_upper)

        @jax.jit
        def run(state, key, env=env, lower=lower, upper=upper):
            def body(carry, k):
                a = jax.random.uniform(k, (args.envs, 6), minval=lower, maxval=upper)
                return jax.vmap(env.step)(carry, a), None

            return jax.lax.scan(body, state, jax.random.split(key, args.steps))[0]

        t0 = time.perf_counter()
        state = jax.block_until_ready(run(state, jax.random.key(1)))
        compile_s = time.perf_counter() - t0
        times = []
        for i in range(5):
            t0 = time.perf_counter()
            state = jax.block_until_ready(run(state, jax.random.key(2 + i)))
            times.append(time.perf_counter() - t0)
        rate = args.envs * args.steps / float(np.median(times))
        out[kinematics] = {"compile_and_first_call_s": compile_s, "env_steps_per_s": rate}
        print(kinematics, out[kinematics], flush=True)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("mode", choices=("check", "time"))
    p.add_argument("--kinematics", choices=("lean", "fused"), default="lean")
    p.add_argument("--random", type=int, default=100_000)
    p.add_argument("--near", type=int, default=100_000)
    p.add_argument("--offset", type=float, default=1e-4, help="rad, near-contact jitter")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--envs", type=int, default=65536)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--out", default="")
    p.add_argument("--overwrite", action="store_true", help="--out may replace any file")
    args = p.parse_args()
    from mara_mjx.cli.common import UserError
    from mara_mjx.runtime import files, outputs

    try:  # a new file or this script's own earlier output, checked before the work
        if args.out:
            ours = lambda path: outputs.written_by(path, COMMAND)  # noqa: E731
            outputs.check_output(args.out, "--out report", ours, args.overwrite)
    except UserError as e:
        raise SystemExit(f"error: {e}") from None
    out = check(args) if args.mode == "check" else timing(args)
    if args.out:
        files.write_atomic(args.out, json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
