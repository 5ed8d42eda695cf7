"""The paper table (results/paper_table/README.md) from orientation_study.py JSON files.

Per task, the paper's evaluation per seed, mean and worst seed per axis beside the
paper, hold, collisions and time to 5 mm and 1 mm.

    python benchmarks/paper_table.py \
        results/paper_table/paper_table_presets.json \
        results/paper_table/paper_table_position_seeds5-9.json \
        results/paper_table/paper_table_presets_MARAOrient_eval_cpu.json \
        results/paper_table/paper_table_presets_MARACollisionOrient_eval_cpu.json

A FILE written by orientation_params_eval.py (saved policies evaluated again, e.g. after a
change of the deployed IK rule) replaces the accuracy of its task's seeds (the times stay
the training run's). FILE[:PICKS] picks results of a file (indices into its results or
variant names, comma separated). A task's seeds are gathered over the files in order (a
seed already taken is not taken again); its preset and overrides are the first file's.
Time to X mm: from the start of the task's study (env built, compile included; the
Python imports, ~3 s, not), the first probe (deterministic policy, the study's
--probe-steps from the reset, mean of 4 episodes) with every axis below X; studies
without a per-seed probe timeline give their training metric's time instead
(det_error_mm). The usage example: results/paper_table/make_readme.sh.
"""

from __future__ import annotations

import gzip
import json
import sys

import numpy as np

PAPER = {
    "MARA": ((5.74, 6.78, 6.38), None),
    "MARACollision": ((5.68, 4.53, 3.13), None),
    "MARAOrient": ((3.03, 8.95, 5.85), (0.71, 1.61, 7.52)),
    "MARACollisionOrient": ((7.43, 4.69, 5.18), (2.62, 4.06, 6.43)),
}


def fmt(a) -> str:
    return ", ".join(f"{x:.2f}" for x in a)


def probe_times(result: dict, thr: float) -> dict[int, float | None]:
    """Per seed: the study time of the first probe with every axis below thr (mm)."""
    seeds = result["seeds"]
    out: dict[int, float | None] = {s: None for s in seeds}
    for row in result.get("timeline", []):
        pos = np.asarray(row["position_mm"]).reshape(len(seeds), -1)
        for i, s in enumerate(seeds):
            if out[s] is None and np.all(pos[i] < thr):
                out[s] = float(row["time_s"])
    return out


def median_time(times: list) -> str:
    got = [t for t in times if t is not None]
    return f"{np.median(got):.0f} ({len(got)}/{len(times)} seeds)" if got else "not reached"


def main(specs: list[str]) -> None:
    chosen, commands, rescored = {}, [], []
    for spec in specs:
        path, _, pick = spec.partition(":")
        opener = gzip.open if path.endswith(".gz") else open  # (the larger records are gzipped)
        with opener(path, "rt") as f:
            data = json.load(f)
        commands.append(f"    {data['command']}   # {data['device']}")
        if "results" not in data:  # orientation_params_eval.py: accuracy re-evaluated
            rescored.append((data["task"], path.rsplit("/", 1)[-1], data["per_seed"]))
            continue
        for i, r in enumerate(data["results"]):
            if pick and not ({str(i), r["variant"]} & set(pick.split(","))):
                continue
            times = {thr: probe_times(r, thr) for thr in (5.0, 1.0)}
            entry = chosen.setdefault(r["task"], {**r, "per_seed": [], "files": []})
            entry["files"].append(path.rsplit("/", 1)[-1])
            taken = {s["seed"] for s in entry["per_seed"]}
            for s in r["per_seed"]:
                if s["seed"] in taken:
                    continue
                probe = "timeline" in r and r["timeline"]
                t5 = times[5.0][s["seed"]] if probe else s.get("time_to_5mm_s")
                t1 = times[1.0][s["seed"]] if probe else s.get("time_to_1mm_s")
                entry["per_seed"].append({**s, "t5": t5, "t1": t1})
    for task, name, rows in rescored:  # the same policies evaluated again: accuracy only
        new = {row["seed"]: row for row in rows}
        entry = chosen[task]
        entry["per_seed"] = [{**s, **new.get(s["seed"], {})} for s in entry["per_seed"]]
        entry["files"].append(f"{name} (accuracy)")
    lines = [
        "# Paper table: each task with its train-CLI preset (issue 11)",
        "",
        "Commands (H100, non-deterministic GPU ops, `JAX_DEFAULT_MATMUL_PRECISION=highest`):",
        "",
        *commands,
        "",
        "The seeds of a task train in one vmapped program (`ppo.train.make_seed_trainer`), so",
        "times are of all its seeds sharing one GPU, from the start of the task's study",
        "(compile included; imports not), at the first probe (the deterministic policy, the",
        "study's probe steps from the reset, 4 episodes) within 5 mm / 1 mm on every axis.",
        "Accuracy: the paper's evaluation per seed (10 episodes, reset noise 0.02 rad, stop",
        "when every axis is within 5 mm), mean over episodes; 'mean' and 'worst' are over",
        "seeds. 'hold': the same episodes run to the horizon (1024 steps), error at the last",
        "step. Preset: `ppo.presets.default_preset`, what `python -m mara_mjx.train --env T`",
        "trains with.",
        "",
        "| task | preset | seeds | reached | position mean (mm) | position worst seed (mm)"
        " | paper (mm) | orientation mean (deg) | orientation worst seed (deg) | paper (deg) |"
        " hold position worst (mm) | hold orientation worst (deg) |"
        " collisions / episode (hold, worst seed) | 5 mm at (s, median) | 1 mm at (s, median) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---:|---:|",
    ]
    for task in PAPER:
        if task not in chosen:
            continue
        r = chosen[task]
        ps = sorted(r["per_seed"], key=lambda s: s["seed"])
        pos = np.array([s["position_mm"] for s in ps])
        ori = np.array([s["orientation_deg"] for s in ps])
        hold = np.array([s["hold_orientation_deg"] for s in ps])
        hold_pos = np.array([s["hold_position_mm"] for s in ps])
        orient = PAPER[task][1] is not None
        preset = r.get("preset", "default")
        seeds = [s["seed"] for s in ps]
        cells = [
            task,
            preset + (f" {json.dumps(r['overrides'])}" if r["overrides"] else ""),
            f"{min(seeds)}-{max(seeds)}"
            if seeds == list(range(min(seeds), max(seeds) + 1))
            else ",".join(map(str, seeds)),
            f"{sum(s['reached'] for s in ps)}/{10 * len(ps)}",
            fmt(pos.mean(0)),
            fmt(pos.max(0)),
            fmt(PAPER[task][0]),
            fmt(ori.mean(0)) if orient else "",
            fmt(ori.max(0)) if orient else "",
            fmt(PAPER[task][1]) if orient else "",
            fmt(hold_pos.max(0)),
            fmt(hold.max(0)) if orient else "",
            f"{max(s['hold_collisions_per_episode'] for s in ps):g}",
            median_time([s["t5"] for s in ps]),
            median_time([s["t1"] for s in ps]),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "Sources per task: "
        + "; ".join(f"{t}: {', '.join(chosen[t]['files'])}" for t in PAPER if t in chosen),
        "",
    ]
    lines += ["Per seed (position mm; orientation deg):", ""]
    for task in PAPER:
        for s in sorted(chosen.get(task, {}).get("per_seed", []), key=lambda s: s["seed"]):
            t5, t1 = (("-" if t is None else f"{t:.1f} s") for t in (s["t5"], s["t1"]))
            lines.append(
                f"- {task} seed {s['seed']}: position {fmt(s['position_mm'])}; orientation "
                f"{fmt(s['orientation_deg'])}; reached {s['reached']}/10; hold collisions per "
                f"episode {s['hold_collisions_per_episode']:g} (before the stop "
                f"{s['collisions']:g}); 5 mm at {t5}, 1 mm at {t1}"
            )
    print("\n".join(lines))


if __name__ == "__main__":
    main(sys.argv[1:])
