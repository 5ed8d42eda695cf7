"""The Orient tasks' deployed last approach alone (the IK step, orient-first with the wrap,
no network) from random collision-free joint postures, without a collision guard, with the
guard as it was before it slid (`git show OLD:mara_mjx/envs/clearance.py`) and with
today's (envs/clearance.keep_clear): how many arms do not converge within 300 steps, how
many paths collide, and the smallest clearance on each path (benchmarks/NOTES.md
section 52). Kinematic, as the train driver: q <- clip(q + dq) on the nominal chain.

    python benchmarks/guard_slide.py [--env MARACollisionOrient] [--postures 3000]
        [--old d10ca83]
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="MARACollisionOrient")
    p.add_argument("--postures", type=int, default=3000)
    p.add_argument("--old", default="d10ca83", help="a commit with the guard before the slide")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=300)
    args = p.parse_args(argv)
    import mara_mjx
    from mara_mjx.envs import task_space as ts
    from mara_mjx.envs.clearance import clearance, keep_clear
    from mara_mjx.envs.geometry import quat_conj, quat_mul
    from mara_mjx.ppo.networks import ik_prior_step

    source = subprocess.run(["git", "show", f"{args.old}:mara_mjx/envs/clearance.py"],
                            capture_output=True, text=True, check=True).stdout  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "old_clearance.py"
        path.write_text(source)
        spec = importlib.util.spec_from_file_location("old_clearance", path)
        old = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(old)
    env = mara_mjx.make(args.env)
    tp = jnp.asarray(env.config.target_pos, jnp.float32)
    tq = jnp.asarray(env.config.target_quat, jnp.float32)
    chain = ts.nominal_chain()
    lo, hi = (np.asarray(x, np.float32) for x in ts.joint_ranges())
    guards = {"none": None, "before the slide": old.keep_clear, "today's": keep_clear}

    def obs_of(q):
        p, quat = chain.tcp(q)
        return jnp.concatenate([q, p - tp, quat_mul(quat, quat_conj(tq)), jnp.zeros(3)])

    def error(q):
        o = obs_of(q)
        return jnp.linalg.norm(o[6:9]), 2 * jnp.arccos(jnp.clip(jnp.abs(o[9]), 0, 1))

    clear = jax.jit(jax.vmap(clearance))
    err = jax.jit(jax.vmap(error))
    rng = np.random.default_rng(args.seed)
    q0 = rng.uniform(lo, hi, size=(args.postures, 6)).astype(np.float32)
    q0 = q0[np.asarray(clear(q0)) > 0.005]
    print(f"{args.env}: {len(q0)} collision-free starts, {args.steps} steps each")
    for name, guard in guards.items():

        def step(q, guard=guard):
            dq, _ = ik_prior_step(obs_of(q), 9, wrap_last=True, orient_first=True)
            if guard is not None:
                dq = guard(q, dq, 0.005)
            return jnp.clip(q + dq, lo, hi)

        f = jax.jit(jax.vmap(step))
        q, smallest, hit = q0.copy(), np.asarray(clear(q0)), np.zeros(len(q0), bool)
        for _ in range(args.steps):
            q = np.asarray(f(q))
            c = np.asarray(clear(q))
            smallest, hit = np.minimum(smallest, c), hit | (c < 0)
        e, a = (np.asarray(x) for x in err(q))
        missed = (e > 0.001) | (a > np.radians(1))
        print(f"  guard {name}: not converged {missed.sum()} ({np.mean(missed):.3f}); "
              f"colliding paths {np.mean(hit):.3f}; smallest clearance on a path, p1 "
              f"{np.percentile(smallest, 1) * 1000:.1f} mm")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
