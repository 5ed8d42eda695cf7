"""Where the IK finish enters the paper's 5 mm box from the edge of its 6-cm zone, with the
step that respects the joint limits (task_space.finish_step, limited_step) and with the
plain step toward the same aim (pose_step, the finish before benchmarks/NOTES.md section
52). Kinematic, as the train driver: q <- clip(q + dq) on the nominal chain, MARA's target.

    python benchmarks/finish_limits.py [--starts 3000] [--family Q1,...,Q6] [--noise 0.15]

Starts: TCP positions 59.9 mm from the target in random directions, each reached by
position IK from a posture near `--family` (default: the CPU teacher's approach posture,
the shoulder at its -2.35 rad stop) with `--noise` rad per joint, clipped to the limits.
Prints, per rule, the largest axis of |e| at the first step inside the box (mean, p95,
worst, share over 1 mm), for all starts and for those with a joint at a limit.
"""

from __future__ import annotations

import argparse
import sys

import jax
import jax.numpy as jnp
import numpy as np

FAMILY = "0.548,-2.272,-1.468,-1.937,-2.201,3.14"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--starts", type=int, default=3000)
    p.add_argument("--family", default=FAMILY)
    p.add_argument("--noise", type=float, default=0.15)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    import mara_mjx
    from mara_mjx.envs import task_space as ts

    target = np.asarray(mara_mjx.make("MARA").config.target_pos, np.float32)
    chain = ts.nominal_chain()
    lo, hi = (np.asarray(x, np.float32) for x in ts.joint_ranges())
    tcp = jax.jit(jax.vmap(lambda q: chain.tcp(q)[0]))

    def aim(e):
        dist = jnp.linalg.norm(e)
        short = e * (1.0 - ts.FINISH_HOLD / jnp.maximum(dist, 1e-12))
        return jnp.where(dist > ts.FINISH_WITHIN * ts.FINISH_HOLD, short, e)

    rules = {
        "plain step (before)": jax.jit(jax.vmap(lambda q, e: ts.pose_step(q, aim(e)))),
        "limited step (finish_step)": jax.jit(jax.vmap(ts.finish_step)),
    }
    rng = np.random.default_rng(args.seed)
    u = rng.normal(size=(args.starts, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    start = target + 0.0599 * u
    family = np.array([float(x) for x in args.family.split(",")], np.float32)
    noise = rng.normal(scale=args.noise, size=(args.starts, 6)).astype(np.float32)
    q = np.clip(family + noise, lo, hi)
    step = jax.jit(jax.vmap(ts.pose_step))
    for _ in range(60):
        q = np.clip(q + np.asarray(step(q, np.asarray(tcp(q)) - start)), lo, hi)
    q = q[np.linalg.norm(np.asarray(tcp(q)) - start, axis=1) < 1e-4]
    at_limit = np.any((q <= lo + 1e-3) | (q >= hi - 1e-3), axis=1)
    print(f"{len(q)} starts on the zone's edge, {at_limit.sum()} with a joint at a limit")
    for name, rule in rules.items():
        qq, entry = q.copy(), np.full((len(q), 3), np.nan)
        for _ in range(40):
            e = np.asarray(tcp(qq)) - target
            new = np.isnan(entry[:, 0]) & np.all(np.abs(e) <= 0.005, axis=1)
            entry[new] = e[new]
            qq = np.clip(qq + np.asarray(rule(qq, e)), lo, hi)
        worst = np.nanmax(np.abs(entry), axis=1) * 1000
        for part, sel in (("all", slice(None)), ("a joint at a limit", at_limit)):
            m = worst[sel]
            print(f"  {name}, {part}: never entered {int(np.isnan(m).sum())}; largest axis at "
                  f"entry mean {np.nanmean(m):.3f} mm, p95 {np.nanpercentile(m, 95):.3f}, "
                  f"worst {np.nanmax(m):.3f}, over 1 mm {np.mean(m > 1):.3f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
