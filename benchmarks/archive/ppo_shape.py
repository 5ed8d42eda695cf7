"""The PPO's shape for time to accuracy (issue 14, item 3): one row per variant.

    python benchmarks/archive/ppo_shape.py --task MARACollisionOrient --seeds 3 --parallel 2 \
        --variant base: --variant mb8:"--num_minibatches 8" ... --out DIR

Each `--variant NAME:FLAGS` (train CLI flags on top of the task's default preset) is
trained twice, with `--probe_reach_steps 100` (the deployed policy's rollout from the
reset, so that the Orient tasks' time to 1 mm is the deployed policy's):

* learning: `python -m mara_mjx.train --env T --seeds N FLAGS` (the N seeds vmapped in
  one program, `--parallel` such programs at a time on the device), which gives per seed
  the env steps to 5 mm and 1 mm and the paper's evaluation of the saved policy (reached,
  mean per-axis position and orientation error): does the shape learn as well?
* speed (unless `--no-speed`): the user's command alone on the device, `--seed 0` with a
  fresh compilation-cache folder (cold), which gives the env steps/s of one run (median
  of progress.csv's rows after the first call), when the first call was done and the
  time to 5 mm and 1 mm from command start.

Then per variant an estimate of a single run's time to 1 mm for the median and the worst
seed: first call done + env steps to 1 mm / env steps/s. Results: <out>/ppo_shape.json and
.md, written after every run (so a cut-off call keeps what finished).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from mara_mjx.ppo import logger

QUIET = ["--plots", "false", "--tensorboard", "false", "--progress", "false"]


def run(cmd: list[str], log: Path, timeout: float) -> tuple[int, float]:
    start = time.monotonic()
    with log.open("w") as f:
        try:
            rc = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, timeout=timeout).returncode
        except subprocess.TimeoutExpired:
            rc = 124
    return rc, time.monotonic() - start


def progress_rate(run_dir: Path) -> tuple[float | None, float | None]:
    """(median steps_per_s of the rows after the first jitted call, as the tta study
    reads it; the first call's time_s)."""
    try:
        progress = logger.read_progress(run_dir, ("time_s", "steps_per_s"))
    except logger.ProgressError:
        return None, None
    t, sps = progress["time_s"], progress["steps_per_s"]
    later = sps[(t > t[0]) & np.isfinite(sps)]
    return (float(np.median(later)) if later.size else None), float(t[0])


def learning(task: str, name: str, flags: str, seeds: int, work: Path, timeout: float) -> dict:
    out = work / f"{name}_seeds"
    cmd = [sys.executable, "-m", "mara_mjx.train", "--env", task, "--seeds", str(seeds),
           "--probe_reach_steps", "100", *QUIET, "--out", str(out),
           *shlex.split(flags)]  # fmt: skip
    rc, wall = run(cmd, work / f"{name}_seeds.log", timeout)
    row: dict = {"command": shlex.join(cmd[1:]), "rc": rc, "wall_s": round(wall, 1)}
    path = out / "seeds.json"
    if path.is_file():
        report = json.loads(path.read_text())
        row["seeds"] = report.get("per_seed")
        row["across_seeds"] = report.get("across_seeds")
    return row


def speed(task: str, name: str, flags: str, work: Path, timeout: float) -> dict:
    out = work / f"{name}_speed"
    cache = tempfile.mkdtemp(prefix=f"cache_{name}_", dir=work)
    cmd = [sys.executable, "-m", "mara_mjx.train", "--env", task, "--seed", "0",
           "--probe_reach_steps", "100", "--evaluate", "false", *QUIET, "--out", str(out),
           "--compilation_cache", cache, *shlex.split(flags)]  # fmt: skip
    rc, wall = run(cmd, work / f"{name}_speed.log", timeout)
    rate, first = progress_rate(out)
    row = {"command": shlex.join(cmd[1:]), "rc": rc, "wall_s": round(wall, 1),
           "steps_per_s": rate, "first_call_done_s": first}  # fmt: skip
    path = out / "summary.json"
    if path.is_file():
        summary = json.loads(path.read_text())
        for mm, rec in summary.get("time_to_accuracy", {}).items():
            row[f"time_to_{mm}_s"] = rec.get("time_s")
            row[f"env_steps_to_{mm}"] = rec.get("env_steps")
        row["command_time_s"] = summary.get("command_time_s")
    return row


def estimate(row: dict) -> None:
    """A single run's time to 1 mm from the learning seeds' env steps and the speed run."""
    sp, seeds = row.get("speed", {}), (row.get("learning", {}).get("seeds") or [])
    steps = [s.get("env_steps_to_1mm") for s in seeds]
    if not (sp.get("steps_per_s") and sp.get("first_call_done_s") is not None and steps):
        return
    finite = sorted(math.inf if s is None else s for s in steps)
    est = [sp["first_call_done_s"] + s / sp["steps_per_s"] for s in finite]
    row["estimate_1mm_s"] = {"median": statistics.median(est), "worst": est[-1]}


def markdown(task: str, rows: dict) -> str:
    lines = [
        f"# PPO shape for time to accuracy: {task}",
        "",
        "| variant | flags | env steps/s (1 run) | first call (s) | 1 mm at (s, seed 0 run) "
        "| env steps to 1 mm (seeds) | est. 1 mm (s): median / worst | reached | "
        "pos. worst (mm) | ori. worst (deg) |",
        "|---|---|---:|---:|---:|---|---|---|---:|---:|",
    ]
    for name, r in rows.items():
        sp, seeds = r.get("speed", {}), r.get("learning", {}).get("seeds") or []
        rate = f"{sp['steps_per_s'] / 1e6:.2f} M" if sp.get("steps_per_s") else "-"
        first = f"{sp['first_call_done_s']:.1f}" if sp.get("first_call_done_s") else "-"
        t1 = sp.get("time_to_1mm_s")
        steps = ", ".join(
            "-" if s.get("env_steps_to_1mm") is None else f"{s['env_steps_to_1mm'] / 1e6:.1f} M"
            for s in seeds
        )
        est = r.get("estimate_1mm_s")
        est_s = f"{est['median']:.1f} / {est['worst']:.1f}" if est else "-"
        reached = ", ".join(f"{s.get('reached')}/{s.get('episodes')}" for s in seeds)
        pos = [max(s["position_error_mm"]) for s in seeds if s.get("position_error_mm")]
        ori = [max(s["orientation_error_deg"]) for s in seeds if s.get("orientation_error_deg")]
        lines.append(
            f"| {name} | `{r['flags']}` | {rate} | {first} | "
            f"{'-' if t1 is None else f'{t1:.1f}'} | {steps} | {est_s} | {reached} | "
            f"{max(pos) if pos else math.nan:.2f} | {max(ori) if ori else math.nan:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--variant", action="append", required=True, help="NAME:FLAGS")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--parallel", type=int, default=2)
    p.add_argument("--no-speed", action="store_true")
    p.add_argument("--timeout", type=float, default=300)
    p.add_argument("--work", type=Path, default=Path("/tmp/ppo_shape"))
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    bad = [v for v in args.variant if ":" not in v or not v.split(":", 1)[0]]
    if bad:
        p.error(f"--variant takes NAME:FLAGS (FLAGS may be empty, e.g. 'base:'), got {bad}")
    variants = dict(v.split(":", 1) for v in args.variant)
    args.work.mkdir(parents=True, exist_ok=True)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = {name: {"flags": flags} for name, flags in variants.items()}

    def save() -> None:
        for r in rows.values():
            estimate(r)
        meta = {"task": args.task, "seeds": args.seeds, "parallel": args.parallel,
                "argv": sys.argv, "xla_flags": os.environ.get("XLA_FLAGS", "")}  # fmt: skip
        (args.out / "ppo_shape.json").write_text(json.dumps({**meta, "rows": rows}, indent=1))
        (args.out / "ppo_shape.md").write_text(markdown(args.task, rows))

    def learn(name: str) -> None:
        rows[name]["learning"] = learning(
            args.task, name, variants[name], args.seeds, args.work, args.timeout
        )
        save()
        print(name, "learning", rows[name]["learning"].get("rc"), flush=True)

    with ThreadPoolExecutor(args.parallel) as pool:
        list(pool.map(learn, variants))
    if not args.no_speed:
        for name, flags in variants.items():
            rows[name]["speed"] = speed(args.task, name, flags, args.work, args.timeout)
            save()
            print(name, "speed", rows[name]["speed"], flush=True)
    print(markdown(args.task, rows))


if __name__ == "__main__":
    main()
