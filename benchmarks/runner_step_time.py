"""The robot-side runner's time per control period over whole episodes, as a robot runs it:
`PolicyRunner.load(policy.onnx)` (onnxruntime, one thread), one arm, stepping the servos'
driver (`--driver real`, nominal physics) of the export's task, every episode to the
horizon; per step the wall time of `runner.step` alone. With the export's commit_rad the
runner runs the policy only on the steps where the arm has arrived or stopped (a held
command costs nothing), so the plan's restarts (tens of ms on a slow core) are paid on
the few steps that choose where the own landing misses.

    python -m mara_mjx.export RUN/seed_S policy.onnx --batch 1
    python benchmarks/runner_step_time.py policy.onnx [--episodes 8] [--velocity 0.5]
        [--seed 1000] [--json OUT.json]

Targets: the env's own resets from `--seed` (the task's target distribution, not the
evaluation's held-out poses). Prints the median, p95, p99 and largest step time, the
share of steps over the control period, and how many steps ran the policy.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("onnx", type=Path)
    p.add_argument("--episodes", type=int, default=8)
    p.add_argument("--velocity", type=float, default=0.5, help="servo speed (rad/s)")
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--json", type=Path, help="also write the figures here (a new file)")
    args = p.parse_args(argv)
    if args.json and args.json.exists():
        print(f"error: {args.json} exists; name a new file", file=sys.stderr)
        return 2
    import jax
    import jax.numpy as jnp
    import onnxruntime as ort

    from mara_mjx.deploy import in_the_loop
    from mara_mjx.deploy.runner import PolicyRunner

    export = in_the_loop.load(args.onnx)
    env = in_the_loop.make_env(export, driver="real", velocity=args.velocity)
    runner = PolicyRunner.load(args.onnx)
    period = 1e3 * float(env.config.control_dt)
    calls = []  # observations the file was run on, per step
    act = runner._policy
    runner._policy = lambda obs: calls.append(len(obs)) or act(obs)
    step = jax.jit(env.step)
    reset = jax.jit(env.reset)
    times, ran, final_mm = [], [], []
    for key in jax.random.split(jax.random.key(args.seed), args.episodes):
        state = reset(key)
        runner.reset()
        for _ in range(env.max_episode_steps):
            q = np.asarray(state.obs[:6], np.float64)
            target = (np.asarray(state.params.target_pos), np.asarray(state.params.target_quat))
            before = len(calls)
            start = time.perf_counter()
            action = runner.step(q, *target)
            times.append(time.perf_counter() - start)
            ran.append(len(calls) > before)
            state = step(state, jnp.asarray(action, jnp.float32))
        final_mm.append(float(1e3 * np.max(np.abs(np.asarray(state.metrics["position_error"])))))
    ms, ran = 1e3 * np.asarray(times[4:]), np.asarray(ran)  # (the first calls warm up)
    figures = {
        "file": str(args.onnx),
        "episodes": args.episodes,
        "steps": int(len(times)),
        "velocity": args.velocity,
        "commit_rad": runner.commit_rad,
        "steps_running_the_policy": int(ran.sum()),
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "steps_over_the_period": int((ms > period).sum()),
        "control_period_ms": period,
        "final_error_mm_max_axis": final_mm,
        "onnxruntime": ort.__version__,
        "machine": f"{platform.platform()}, {platform.processor() or platform.machine()}",
        "command": " ".join(sys.argv),
    }
    print(
        f"{args.onnx}: {figures['steps']} steps of {args.episodes} episodes at "
        f"{args.velocity} rad/s (commit_rad {runner.commit_rad}); the policy ran on "
        f"{figures['steps_running_the_policy']}; runner.step median {figures['median_ms']:.2f} ms, "
        f"p95 {figures['p95_ms']:.1f}, p99 {figures['p99_ms']:.1f}, max {figures['max_ms']:.1f}; "
        f"{figures['steps_over_the_period']} steps over the {period:.0f}-ms period; final "
        f"error per episode (mm, largest axis) {', '.join(f'{x:.2f}' for x in final_mm)}"
    )
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
