"""The paper table (issue 11) from orientation_study.py JSON files: per task, the paper's
evaluation per seed, mean and worst seed per axis beside the paper, hold, collisions and
time to 1 mm. Each task is taken from the first file and variant that has it.

    python benchmarks/paper_table.py results/paper_table/orient_tasks.json:0,2 \
        results/paper_table/position_tasks.json:default > results/paper_table/README.md

FILE:PICKS picks results of a file (indices into its results or variant names, comma
separated). orient_tasks.json ran the preset of that time with train_reward
"beta=0.5,gamma=0.02", which is the default preset now.
"""

from __future__ import annotations

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


def main(specs: list[str]) -> None:
    chosen, commands = {}, []
    for spec in specs:
        path, _, pick = spec.partition(":")
        data = json.load(open(path))
        commands.append(f"    {data['command']}   # {data['device']}")
        for i, r in enumerate(data["results"]):
            if pick and not ({str(i), r["variant"]} & set(pick.split(","))):
                continue
            chosen.setdefault(r["task"], r)
    lines = [
        "# Paper table: 5 seeds per task, the default preset (issue 11)",
        "",
        "Commands (non-deterministic GPU ops, `JAX_DEFAULT_MATMUL_PRECISION=highest`):",
        "",
        *commands,
        "",
        "The seeds of a task train in one vmapped program (`ppo.train.make_seed_trainer`), so",
        "times are of 5 runs sharing one GPU, from script start, compile included. Accuracy:",
        "the paper's evaluation per seed (10 episodes, reset noise 0.02 rad, stop when every",
        "axis is within 5 mm), mean over episodes; 'mean' and 'worst' are over seeds. 'hold':",
        "the same episodes run to the horizon (1024 steps), error at the last step. The",
        "orientation curriculum (train_reward) does not change MARA / MARACollision (their",
        "reward has no orientation factor), so their rows come from the run before it.",
        "",
        "| task | PPO overrides of the run | reached | position mean (mm)"
        " | position worst seed (mm)"
        " | paper (mm) | orientation mean (deg) | orientation worst seed (deg) | paper (deg) |"
        " hold orientation worst (deg) | collisions / episode (hold, worst seed) |"
        " 1 mm at (s, median over seeds) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---:|",
    ]
    for task in PAPER:
        if task not in chosen:
            continue
        r = chosen[task]
        ps = r["per_seed"]
        pos = np.array([s["position_mm"] for s in ps])
        ori = np.array([s["orientation_deg"] for s in ps])
        hold = np.array([s["hold_orientation_deg"] for s in ps])
        t1 = [s["time_to_1mm_s"] for s in ps if s["time_to_1mm_s"] is not None]
        orient = PAPER[task][1] is not None
        cells = [
            task,
            json.dumps(r["overrides"]) if r["overrides"] else "(default)",
            f"{sum(s['reached'] for s in ps)}/{10 * len(ps)}",
            fmt(pos.mean(0)),
            fmt(pos.max(0)),
            fmt(PAPER[task][0]),
            fmt(ori.mean(0)) if orient else "",
            fmt(ori.max(0)) if orient else "",
            fmt(PAPER[task][1]) if orient else "",
            fmt(hold.max(0)) if orient else "",
            f"{max(s['hold_collisions_per_episode'] for s in ps):.0f}",
            f"{np.median(t1):.0f} ({len(t1)}/{len(ps)} seeds)" if t1 else "not reached",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Per seed (position mm; orientation deg):", ""]
    for task in PAPER:
        for s in chosen.get(task, {}).get("per_seed", []):
            t = s["time_to_1mm_s"]
            lines.append(
                f"- {task} seed {s['seed']}: position {fmt(s['position_mm'])}; orientation "
                f"{fmt(s['orientation_deg'])}; reached {s['reached']}/10; hold collisions per "
                f"episode {s['hold_collisions_per_episode']:.0f}; 1 mm at "
                f"{'-' if t is None else f'{t:.1f} s'}"
            )
    print("\n".join(lines))


if __name__ == "__main__":
    main(sys.argv[1:])
