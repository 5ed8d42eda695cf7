"""Where the time of one batched train-driver step goes (GPU profiling aid).

Times, at each size, under vmap + lax.scan with random joint targets drawn inside the
scan (the `env` study's harness), each stage compiled apart (`compile_s`) and timed as the
median of `--repeats` calls after a warm-up:
  draws         the harness alone: the uniform random joint targets, summed
  pose          draws + the pose pass with collision (Arm.pose_with, `--kinematics`)
  env.step      the task step (pose + observation + reward + reset rules), no auto-reset
  batched       BatchedEnv.step (env.step + auto-reset + episode statistics), the
                default "select" reset strategy: a reset computed for every env each step
  batched_cond  the same with reset_strategy="cond": the reset only on steps where an
                episode ended (the tasks truncate every env together)
  loop, loop_cond
                BatchedEnv.step in the `env` and `limit` studies' own scan body
                (`bench.env.make_step_body`: the same step and draws, plus a per-step
                output, the fraction of envs that collided), each call from the same state
  loop_carried, loop_cond_carried
                the same, the state carried from call to call, as those studies time it
                (the loop stages' programs, so their compile shows as 0 s)
The loop stages separate the two harnesses' differences: on an H100 at 262,144 envs the
fused step's cond led select by 20% in `limit` and trailed by 14% in `batched_cond`
(benchmarks/NOTES.md section 70). Each stage's kernels are recorded too (the launching
instructions of its optimised module, the scan's body counted once:
`mara_mjx.bench.limit.kernel_count`).

    python benchmarks/profile_step.py --task MARACollisionOrient --kinematics fused \
        --sizes 262144 1048576 --out runs/profile_step.json

Writes JSON to --out after every stage (a new file, or this script's own earlier report;
`--overwrite` to replace anything else).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import mara_mjx
from mara_mjx.bench.env import make_rollout
from mara_mjx.bench.limit import kernel_count
from mara_mjx.bench.runner import device_info, versions
from mara_mjx.envs.base import KINEMATICS
from mara_mjx.envs.batched import BatchedEnv

COMMAND = "python benchmarks/profile_step.py"


def timed(fn, x, key, repeats=5, carried=False) -> float:
    """The median wall-clock of `repeats` calls after a warm-up call; `carried`: each call
    starts from the previous call's (state, key), else all from (x, key)."""
    out = jax.block_until_ready(fn(x, key))
    ts = []
    for _ in range(repeats):
        if carried:
            x, key = out[0], out[1]
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(x, key))
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


STAGES = ("draws", "pose", "env.step", "batched", "batched_cond", "loop", "loop_cond")
STAGES += ("loop_carried", "loop_cond_carried")


def stages(env, n: int, steps: int) -> dict:
    """name -> (a jitted scan of `steps` steps: (x, key) -> (x, key, ...), its first x,
    whether calls carry the state)."""
    arm, kin = env.arm, env.config.kinematics
    lo, hi = jnp.asarray(env.joint_lower), jnp.asarray(env.joint_upper)

    def scan(stage):
        def body(carry, _):
            x, key = carry
            key, k = jax.random.split(key)
            a = jax.random.uniform(k, (n, 6), minval=lo, maxval=hi)
            return (stage(x, a), key), None

        return jax.jit(lambda x, key: jax.lax.scan(body, (x, key), None, length=steps)[0])

    def pose(x, a):
        ps = jax.vmap(lambda q: arm.pose_with(q, kin))(a)
        return x + ps.tcp_pos.sum() + ps.collided.sum()

    benv = BatchedEnv(env, n)
    benv_cond = BatchedEnv(env, n, reset_strategy="cond")
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), n))
    bstate = benv.reset(jax.random.key(0))
    loop, loop_cond = make_rollout(benv, steps), make_rollout(benv_cond, steps)
    return {
        "draws": (scan(lambda x, a: x + a.sum()), jnp.zeros(()), False),
        "pose": (scan(pose), jnp.zeros(()), False),
        "env.step": (scan(jax.vmap(env.step)), states, False),
        "batched": (scan(benv.step), bstate, False),
        "batched_cond": (scan(benv_cond.step), bstate, False),
        "loop": (loop, bstate, False),
        "loop_cond": (loop_cond, bstate, False),
        "loop_carried": (loop, bstate, True),
        "loop_cond_carried": (loop_cond, bstate, True),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--kinematics", default="lean", choices=KINEMATICS)
    p.add_argument("--sizes", nargs="+", type=int, default=[16384, 65536])
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES))
    p.add_argument("--out", type=Path, default=Path("runs/profile_step.json"))
    p.add_argument("--overwrite", action="store_true", help="--out may replace any file")
    args = p.parse_args()
    from mara_mjx.cli.common import UserError
    from mara_mjx.runtime import files, outputs

    try:  # a new file or this script's own earlier output, checked before the work
        ours = lambda path: outputs.written_by(path, COMMAND)  # noqa: E731
        outputs.check_output(args.out, "--out report", ours, args.overwrite)
    except UserError as e:
        raise SystemExit(f"error: {e}") from None
    env = mara_mjx.make(args.task, kinematics=args.kinematics)
    out = {
        "command": f"{COMMAND} " + " ".join(sys.argv[1:]),
        "device": device_info(),
        "versions": versions(),
        "records": [],
    }
    for n in args.sizes:
        for name, (fn, x0, carried) in stages(env, n, args.steps).items():
            if name not in args.stages:
                continue
            key = jax.random.key(1)
            t0 = time.perf_counter()
            compiled = fn.lower(x0, key).compile()
            compile_s = time.perf_counter() - t0
            kernels = kernel_count(compiled.as_text())
            med = timed(compiled, x0, key, args.repeats, carried)
            rec = {
                "task": args.task,
                "kinematics": args.kinematics,
                "stage": name,
                "num_envs": n,
                "kernels": kernels,
                "compile_s": compile_s,
                "step_us": 1e6 * med / args.steps,
                "steps_per_s": n * args.steps / med,
            }
            out["records"].append(rec)
            files.write_atomic(args.out, json.dumps(out, indent=1))  # a cut run keeps its rows
            print(
                f"n={n:>8d} {name:12s} {rec['steps_per_s'] / 1e6:9.2f} M/s"
                f"  {rec['step_us']:8.1f} us/step  {kernels:4d} kernels"
                f"  compile {rec['compile_s']:.1f} s",
                flush=True,
            )


if __name__ == "__main__":
    main()
