"""Where the time of one batched train-driver step goes (GPU profiling aid).

Times, at each size, under vmap + lax.scan with random joint positions:
  kinematics   mjx.kinematics only
  pose         kinematics + mjx.collision over the listed pairs (Arm.pose)
  env.step     the task step (pose + observation + reward + reset rules), no auto-reset
  batched      BatchedEnv.step (env.step + auto-reset + episode statistics), the
               default "select" reset strategy
  batched_cond the same with reset_strategy="cond"
  batched_v0   the first version, for before/after in one run: "cond" strategy and a
               reset that also ran collision detection

    python benchmarks/profile_step.py --task MARACollisionOrient --sizes 16384 65536

Writes JSON to --out (default benchmarks/results/profile_step.json).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
from mujoco import mjx

import mara_mjx
from mara_mjx.bench.runner import device_info, versions
from mara_mjx.envs.batched import BatchedEnv


class FullPoseReset:
    """The env with the first version's reset (kinematics + collision)."""

    def __init__(self, env):
        self._env = env

    def __getattr__(self, name):
        return getattr(self._env, name)

    def reset(self, key, params=None):
        arm = self._env.arm
        pose = arm.pose
        arm.pose = lambda q, collide=True: pose(q, True)
        try:
            return self._env.reset(key, params)
        finally:
            arm.pose = pose


def timed(fn, *args, repeats=5):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t0)
    return first, statistics.median(ts), out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--sizes", nargs="+", type=int, default=[16384, 65536])
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/profile_step.json"))
    args = p.parse_args()
    env = mara_mjx.make(args.task)
    arm = env.arm
    lo, hi = jnp.asarray(env.joint_lower), jnp.asarray(env.joint_upper)
    records = []
    for n in args.sizes:
        benv = BatchedEnv(env, n)
        benv_cond = BatchedEnv(env, n, reset_strategy="cond")
        benv_v0 = BatchedEnv(FullPoseReset(env), n, reset_strategy="cond")

        def scan(stage):
            def body(carry, _):
                x, key = carry
                key, k = jax.random.split(key)
                a = jax.random.uniform(k, (n, 6), minval=lo, maxval=hi)
                x, out = stage(x, a)
                return (x, key), out

            return jax.jit(lambda x, key: jax.lax.scan(body, (x, key), None, length=args.steps)[0])

        def kin(x, a):
            d = jax.vmap(lambda q: mjx.kinematics(arm.mjx_model, arm._data0.replace(qpos=q)))(a)
            return x + d.site_xpos[:, arm.tcp_site].sum(), None

        def pose(x, a):
            ps = jax.vmap(arm.pose)(a)
            return x + ps.tcp_pos.sum() + ps.collided.sum(), None

        states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), n))
        bstate = benv.reset(jax.random.key(0))
        stages = {
            "kinematics": (scan(kin), jnp.zeros(())),
            "pose": (scan(pose), jnp.zeros(())),
            "env.step": (scan(lambda s, a: (jax.vmap(env.step)(s, a), None)), states),
            "batched": (scan(lambda s, a: (benv.step(s, a), None)), bstate),
            "batched_cond": (scan(lambda s, a: (benv_cond.step(s, a), None)), bstate),
            "batched_v0": (scan(lambda s, a: (benv_v0.step(s, a), None)), bstate),
        }
        for name, (fn, x0) in stages.items():
            first, med, _ = timed(fn, x0, jax.random.key(1))
            rec = {
                "task": args.task,
                "stage": name,
                "num_envs": n,
                "compile_s": first - med,
                "steps_per_s": n * args.steps / med,
            }
            records.append(rec)
            print(
                f"n={n:>6d} {name:12s} {rec['steps_per_s'] / 1e6:8.2f} M/s"
                f"  compile {rec['compile_s']:.1f} s",
                flush=True,
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps({"device": device_info(), "versions": versions(), "records": records}, indent=2)
    )


if __name__ == "__main__":
    main()
