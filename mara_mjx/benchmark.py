"""Measured throughput of mara_mjx: `python -m mara_mjx.benchmark STUDY [options]`.

Studies:
  env   env steps/s of the batched, jitted, auto-resetting step (`BatchedEnv.step`
        inside a `lax.scan`, random joint targets drawn inside the scan) for each task
        and driver over a sweep of environment counts. Compile time (first call) is
        reported apart from the steady state (median of `--repeats` timed calls after a
        warm-up). For the real driver, physics steps/s = env steps/s x substeps.

Output: a table on the terminal, and in `--out` (default benchmarks/results/):
  <study>.json (records + device, versions, command), <study>.md, <study>.png.
`--quick` runs tiny sizes for a CPU smoke test.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

import mara_mjx
from mara_mjx.envs.batched import BatchedEnv

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


def versions() -> dict[str, str]:
    import flax
    import mujoco
    import optax

    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": jax.lib.__version__ if hasattr(jax.lib, "__version__") else "",
        "mujoco": mujoco.__version__,
        "flax": flax.__version__,
        "optax": optax.__version__,
        "mara_mjx": mara_mjx.__version__,
    }


def device_info() -> dict[str, Any]:
    dev = jax.devices()[0]
    return {
        "platform": dev.platform,
        "device_kind": dev.device_kind,
        "device_count": jax.device_count(),
        "host": platform.node(),
    }


def _peak_memory() -> int | None:
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use")


def make_rollout(benv: BatchedEnv, steps: int):
    """A jitted function running `steps` batched steps with uniform random joint targets."""
    lower, upper = jnp.asarray(benv.env.joint_lower), jnp.asarray(benv.env.joint_upper)

    def body(carry, _):
        state, key = carry
        key, action_key = jax.random.split(key)
        action = jax.random.uniform(action_key, (benv.num_envs, 6), minval=lower, maxval=upper)
        state = benv.step(state, action)
        return (state, key), state.metrics["collided"].mean()

    @jax.jit
    def rollout(state, key):
        (state, key), collided = jax.lax.scan(body, (state, key), None, length=steps)
        return state, key, collided.mean()

    return rollout


def time_env(task: str, driver: str, num_envs: int, steps: int, repeats: int) -> dict[str, Any]:
    """Compile time and steady-state env steps/s of one (task, driver, num_envs)."""
    env = mara_mjx.make(task, driver=driver)
    benv = BatchedEnv(env, num_envs)
    rollout = make_rollout(benv, steps)
    state = jax.jit(benv.reset)(jax.random.key(0))
    key = jax.random.key(1)
    jax.block_until_ready(state)
    t0 = time.perf_counter()
    state, key, collided = jax.block_until_ready(rollout(state, key))
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state, key, collided = jax.block_until_ready(rollout(state, key))
        times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    sps = num_envs * steps / median
    return {
        "task": task,
        "driver": driver,
        "num_envs": num_envs,
        "steps_per_call": steps,
        "compile_s": max(first - median, 0.0),
        "first_call_s": first,
        "median_call_s": median,
        "env_steps_per_s": sps,
        "physics_steps_per_s": sps * env.n_substeps if driver == "real" else None,
        "collision_fraction": float(collided),
        "peak_device_bytes": _peak_memory(),
    }


def env_study(args: argparse.Namespace) -> list[dict[str, Any]]:
    records = []
    for driver in args.drivers:
        sizes = args.sizes if driver == "train" else args.real_sizes
        for task in args.tasks:
            for n in sizes:
                try:
                    rec = time_env(task, driver, n, args.steps, args.repeats)
                except Exception as e:  # out of memory at the top of a sweep ends it
                    if "RESOURCE_EXHAUSTED" not in str(e) and "out of memory" not in str(e):
                        raise
                    print(f"{task} {driver} n={n}: out of device memory, sweep stops")
                    break
                records.append(rec)
                print(
                    f"{task:20s} {driver:5s} n={n:>7d}"
                    f"  {rec['env_steps_per_s'] / 1e6:9.3f} M steps/s"
                    f"  compile {rec['compile_s']:6.1f} s",
                    flush=True,
                )
    return records


def write_env_results(records: list[dict[str, Any]], out: Path, meta: dict[str, Any]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "env.json").write_text(json.dumps({**meta, "records": records}, indent=2))
    lines = [
        "# env study: batched step throughput",
        "",
        f"Device: {meta['device']['device_kind']} ({meta['device']['platform']}); "
        f"versions: jax {meta['versions']['jax']}, mujoco {meta['versions']['mujoco']}.",
        "",
        f"Command: `{meta['command']}`",
        "",
        "| task | driver | envs | env steps/s | physics steps/s | compile (s) |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for r in records:
        phys = f"{r['physics_steps_per_s'] / 1e6:.2f} M" if r["physics_steps_per_s"] else ""
        lines.append(
            f"| {r['task']} | {r['driver']} | {r['num_envs']:,} | "
            f"{r['env_steps_per_s'] / 1e6:.2f} M | {phys} | {r['compile_s']:.1f} |"
        )
    (out / "env.md").write_text("\n".join(lines) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for driver in sorted({r["driver"] for r in records}):
        for task in sorted({r["task"] for r in records}):
            rs = [r for r in records if r["task"] == task and r["driver"] == driver]
            if rs:
                ax.plot(
                    [r["num_envs"] for r in rs],
                    [r["env_steps_per_s"] for r in rs],
                    marker="o",
                    linestyle="-" if driver == "train" else "--",
                    label=f"{task} ({driver})",
                )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("environments")
    ax.set_ylabel("env steps / s")
    ax.set_title(f"mara_mjx batched step, {meta['device']['device_kind']}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "env.png", dpi=120)
    plt.close(fig)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m mara_mjx.benchmark",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("study", choices=["env"], help="which study to run")
    p.add_argument("--tasks", nargs="+", default=list(mara_mjx.registered()))
    p.add_argument("--drivers", nargs="+", default=["train", "real"], choices=["train", "real"])
    p.add_argument(
        "--sizes",
        nargs="+",
        type=int,
        default=[1024, 16384, 65536],
        help="environment counts for the train driver",
    )
    p.add_argument(
        "--real-sizes",
        nargs="+",
        type=int,
        default=[16384],
        help="environment counts for the real driver",
    )
    p.add_argument("--steps", type=int, default=100, help="env steps per timed call")
    p.add_argument("--repeats", type=int, default=5, help="timed calls after the first")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="results folder")
    p.add_argument("--quick", action="store_true", help="tiny sizes: a CPU smoke run")
    args = p.parse_args(argv)
    unknown = sorted(set(args.tasks) - set(mara_mjx.registered()))
    if unknown:
        p.error(f"unknown task(s) {unknown}; registered: {list(mara_mjx.registered())}")
    if min(args.sizes + args.real_sizes) < 1 or args.steps < 1 or args.repeats < 1:
        p.error("--sizes, --real-sizes, --steps and --repeats must be positive")
    if args.quick:
        args.sizes, args.real_sizes, args.steps, args.repeats = [4], [4], 4, 1
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        probe = args.out / ".write_test"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        p.error(f"output folder {args.out} is not writable: {e}")
    return args


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    meta = {
        "study": args.study,
        "command": "python -m mara_mjx.benchmark "
        + " ".join(sys.argv[1:] if argv is None else argv),
        "versions": versions(),
        "device": device_info(),
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    records = env_study(args)
    write_env_results(records, args.out, meta)
    print(f"wrote {args.out}/env.json, env.md, env.png")


if __name__ == "__main__":
    main()
