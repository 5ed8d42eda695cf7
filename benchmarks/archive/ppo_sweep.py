"""Time to accuracy of PPO for several rollout shapes, then the chosen shape on every task.

    python benchmarks/archive/ppo_sweep.py --task MARACollisionOrient \
        --shapes 1024x32 2048x32 4096x16 8192x8 --total 100000000 --final-total 200000000

For each `ENVSxSTEPS[@REWARD_SCALE]` shape it runs `python -m mara_mjx.train` (minibatches of about
2048 transitions, every other setting from the default preset) and reads the wall-clock
time from command start (compile included) at which the deterministic mean per-axis
error (`det_error_mm`) first fell below 5 mm and 1 mm. The fastest shape to 5 mm (ties
broken by 1 mm) is then trained on every task (`--final-tasks`), with the paper's
accuracy evaluation. Results: <out>/ppo_sweep.json, .md and a plot of error against
wall-clock.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import time
from pathlib import Path


def read_progress(path: Path) -> list[dict[str, float]]:
    if not path.is_file():
        return []
    with path.open() as f:
        return [
            {k: float(v) if v not in ("", None) else math.nan for k, v in row.items()}
            for row in csv.DictReader(f)
        ]


def first_below(rows: list[dict[str, float]], mm: float) -> float | None:
    for r in rows:
        if r.get("det_error_mm", math.inf) < mm:
            return r["time_s"]
    return None


def train(
    task: str,
    envs: int,
    steps: int,
    scale: float,
    total: int,
    out: Path,
    timeout: float,
    extra: list[str],
) -> dict:
    minibatches = max(1, envs * steps // 2048)
    cmd = [
        sys.executable,
        "-m",
        "mara_mjx.train",
        "--env",
        task,
        "--num_envs",
        str(envs),
        "--num_steps",
        str(steps),
        "--num_minibatches",
        str(minibatches),
        "--reward_scale",
        str(scale),
        "--total_timesteps",
        str(total),
        "--out",
        str(out),
        "--progress",
        "false",
        "--checkpoint_every",
        "100000",
        *extra,
    ]
    t0 = time.monotonic()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        status = "ok" if proc.returncode == 0 else f"exit {proc.returncode}: {proc.stderr[-500:]}"
    except subprocess.TimeoutExpired:
        status = f"stopped at the {timeout:.0f} s limit"
    rows = read_progress(out / "progress.csv")
    rec = {
        "task": task,
        "num_envs": envs,
        "num_steps": steps,
        "num_minibatches": minibatches,
        "reward_scale": scale,
        "total_timesteps": total,
        "status": status,
        "wall_s": time.monotonic() - t0,
        "time_to_5mm_s": first_below(rows, 5.0),
        "time_to_1mm_s": first_below(rows, 1.0),
        "env_steps": rows[-1]["env_steps"] if rows else 0,
        "final_det_error_mm": rows[-1]["det_error_mm"] if rows else None,
        "steps_per_s": rows[-1]["env_steps"] / rows[-1]["time_s"] if rows else None,
        "command": " ".join(cmd[1:]),
        "curve": [(r["time_s"], r["det_error_mm"]) for r in rows],
    }
    summary = out / "summary.json"
    if summary.is_file():
        rec["eval"] = json.loads(summary.read_text()).get("eval")
    print(
        f"{task} {envs}x{steps}@{scale}: 5 mm at {rec['time_to_5mm_s']} s, 1 mm at "
        f"{rec['time_to_1mm_s']} s, {rec['steps_per_s'] or 0:.3g} steps/s, {status}",
        flush=True,
    )
    return rec


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--shapes", nargs="+", default=["1024x32", "2048x32", "4096x16", "8192x8"])
    p.add_argument("--total", type=int, default=100_000_000)
    p.add_argument("--timeout", type=float, default=120.0)
    p.add_argument("--final-tasks", nargs="*", default=[])
    p.add_argument("--final-total", type=int, default=200_000_000)
    p.add_argument("--runs", type=Path, default=Path("/tmp/ppo_sweep"))
    p.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    p.add_argument("extra", nargs=argparse.REMAINDER, help="-- then more train flags")
    args = p.parse_args()
    extra = [a for a in args.extra if a != "--"]
    sweep = []
    for shape in args.shapes:
        dims, _, scale = shape.lower().partition("@")
        envs, steps = (int(x) for x in dims.split("x"))
        sweep.append(
            train(
                args.task,
                envs,
                steps,
                float(scale or 1.0),
                args.total,
                args.runs / f"{args.task}-{shape}",
                args.timeout,
                extra,
            )
        )
    key = lambda r: (r["time_to_5mm_s"] or math.inf, r["time_to_1mm_s"] or math.inf)  # noqa: E731
    best = min(sweep, key=key)
    finals = [
        train(
            t,
            best["num_envs"],
            best["num_steps"],
            best["reward_scale"],
            args.final_total,
            args.runs / f"final-{t}",
            args.timeout * 2,
            extra,
        )
        for t in args.final_tasks
    ]
    args.out.mkdir(parents=True, exist_ok=True)
    result = {
        "command": " ".join(sys.argv),
        "sweep": sweep,
        "best": f"{best['num_envs']}x{best['num_steps']}@{best['reward_scale']}",
        "final": finals,
    }
    (args.out / "ppo_sweep.json").write_text(json.dumps(result, indent=1))
    fmt = lambda x: "not reached" if x is None else f"{x:.1f} s"  # noqa: E731
    lines = [
        "# PPO: time to accuracy by rollout shape (wall-clock from command start)",
        "",
        f"Command: `{result['command']}`",
        "",
        "| task | envs x steps | reward scale | to 5 mm | to 1 mm | env steps/s | final (mm) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in sweep + finals:
        lines.append(
            f"| {r['task']} | {r['num_envs']} x {r['num_steps']} | {r['reward_scale']} | "
            f"{fmt(r['time_to_5mm_s'])} | {fmt(r['time_to_1mm_s'])} | "
            f"{(r['steps_per_s'] or 0) / 1e6:.2f} M | {r['final_det_error_mm'] or math.nan:.2f} |"
        )
    (args.out / "ppo_sweep.md").write_text("\n".join(lines) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in sweep + finals:
        if r["curve"]:
            t, e = zip(*r["curve"], strict=True)
            ax.plot(
                t,
                e,
                label=f"{r['task']} {r['num_envs']}x{r['num_steps']} scale {r['reward_scale']}",
            )
    ax.axhline(5.0, color="k", lw=0.8, ls="--")
    ax.axhline(1.0, color="k", lw=0.8, ls=":")
    ax.set_yscale("log")
    ax.set_xlabel("wall-clock since command start (s)")
    ax.set_ylabel("deterministic mean per-axis error (mm)")
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.out / "ppo_sweep.png", dpi=120)


if __name__ == "__main__":
    main()
