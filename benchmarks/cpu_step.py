"""Batched train-driver env steps on the CPU: the effect of mara_mjx/_xla.py's flag.

    python benchmarks/cpu_step.py                                             # flag set on import
    XLA_FLAGS=--xla_cpu_use_fusion_emitters=true python benchmarks/cpu_step.py  # XLA's default

Times 9 steps of --envs environments (BatchedEnv.step under lax.scan, random actions)
after a compile call, and prints the mean reward so the two runs can be compared.
"""

from __future__ import annotations

import argparse
import os
import time

import jax

import mara_mjx  # sets XLA_FLAGS; importing jax first is fine, it starts no backend
from mara_mjx.envs.batched import BatchedEnv


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--envs", type=int, default=256)
    args = p.parse_args()
    benv = BatchedEnv(mara_mjx.make(args.task), args.envs)
    state = jax.jit(benv.reset)(jax.random.key(0))

    @jax.jit
    def roll(state, key):
        def body(state, k):
            a = jax.random.uniform(k, (args.envs, benv.action_size), minval=-1, maxval=1)
            state = benv.step(state, a)
            return state, state.reward

        return jax.lax.scan(body, state, jax.random.split(key, 9))

    t0 = time.perf_counter()
    state, r = jax.block_until_ready(roll(state, jax.random.key(0)))
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    state, r = jax.block_until_ready(roll(state, jax.random.key(1)))
    print(
        f"XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r} compile+first {compile_s:.1f} s, "
        f"9 steps of {args.envs} envs {time.perf_counter() - t0:.4f} s, "
        f"mean reward {float(r.mean()):.6f}"
    )


if __name__ == "__main__":
    main()
