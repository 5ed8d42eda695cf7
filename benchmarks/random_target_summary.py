"""Random-target studies as a table and a figure, per seed and over seeds.

Per seed the 1,000-pose evaluation of `random_target_study.py` (mean, p95 and worst per
axis, within 5 / 1 mm, orientation, collisions, the real driver where measured), then the
mean over seeds and the worst seed per axis.

    python benchmarks/random_target_summary.py \
        benchmarks/results/random_target/study27_ik_gate_0.1.json \
        benchmarks/results/random_target/study27_ik_gate_0.1_seeds5-9.json \
        --out benchmarks/results/random_target/summary

writes OUT.md and OUT.png. Studies of the same (task, variant) are merged (seeds in
separate runs of one command line).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _fmt(v) -> str:
    return ", ".join(f"{x:.2f}" for x in v)


def load(paths: list[Path]) -> dict[tuple[str, str], dict]:
    """(task, variant) -> {"commands", "device", "seeds": [per-seed summary], "train_s"};
    results merge only where their PPO config, env overrides and device agree, and no
    seed repeats (SystemExit naming the files otherwise)."""
    groups: dict[tuple[str, str], dict] = {}
    for path in paths:
        data = json.loads(path.read_text())
        for r in data["results"]:
            key = (r["task"], r["variant"])
            same = json.dumps([r["config"], r["env_overrides"], data["device"]], sort_keys=True)
            g = groups.setdefault(
                key,
                {
                    "commands": [],
                    "device": data["device"],
                    "seeds": [],
                    "train_s": [],
                    "same": same,
                },
            )
            if g["same"] != same:
                raise SystemExit(f"{path}: {key} differs in config, env or device from before")
            if {s["seed"] for s in g["seeds"]} & {s["seed"] for s in r["per_seed"]}:
                raise SystemExit(f"{path}: {key} repeats a seed of an earlier file")
            g["commands"].append(data["command"])
            g["seeds"].extend(r["per_seed"])
            g["train_s"].append(r["train_s"])
    return groups


def table(task: str, variant: str, g: dict) -> str:
    seeds = sorted(g["seeds"], key=lambda s: s["seed"])
    orient = "orientation_error_deg" in seeds[0]
    real = any("real_driver" in s for s in seeds)
    head = ["seed", "pos mean x, y, z (mm)", "pos p95 (mm)", "worst |e| (mm)", "within 5 / 1 mm"]
    if orient:
        head += ["ori mean x, y, z (deg)", "ori p95 (deg)", "within 5 mm & 5 deg / 1 mm & 1 deg"]
    head += ["episodes with collisions"]
    if real:
        head += ["real driver: within 5 mm, ori mean (deg)"]
    lines = [
        f"### {task}, {variant}",
        "",
        f"Device: {g['device']}; training {', '.join(f'{t:.0f}' for t in g['train_s'])} s "
        "(seeds vmapped in one program per command). Commands:",
        "",
        *[f"    {c}" for c in g["commands"]],
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for s in seeds:
        pe = s["position_error_mm"]
        row = [
            str(s["seed"]),
            _fmt(pe["mean"]),
            _fmt(pe["p95"]),
            f"{s['position_error_norm_mm']['max']:.1f}",
            f"{100 * s['within_mm']['5']:.1f}% / {100 * s['within_mm']['1']:.1f}%",
        ]
        if orient:
            oe = s["orientation_error_deg"]
            both = s["within_mm_and_deg"]
            row += [
                _fmt(oe["mean"]),
                _fmt(oe["p95"]),
                f"{100 * both['5 mm, 5 deg']:.1f}% / {100 * both['1 mm, 1 deg']:.1f}%",
            ]
        row += [str(s["episodes_with_collisions"])]
        if real:
            rd = s.get("real_driver")
            row += [
                f"{100 * rd['within_mm']['5']:.1f}%, "
                + _fmt(rd.get("orientation_error_deg", {}).get("mean", []))
                if rd
                else "-"
            ]
        lines.append("| " + " | ".join(row) + " |")
    pm = np.array([s["position_error_mm"]["mean"] for s in seeds])
    agg = [f"mean over {len(seeds)} seeds", _fmt(pm.mean(0)), "", "", ""]
    worst = ["worst seed per axis", _fmt(pm.max(0)), "", "", ""]
    if orient:
        om = np.array([s["orientation_error_deg"]["mean"] for s in seeds])
        agg += [_fmt(om.mean(0)), "", ""]
        worst += [_fmt(om.max(0)), "", ""]
    agg += [""] + ([""] if real else [])
    worst += [""] + ([""] if real else [])
    lines += ["| " + " | ".join(agg) + " |", "| " + " | ".join(worst) + " |", ""]
    return "\n".join(lines)


def figure(groups: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(groups), 2, figsize=(11, 3.2 * len(groups)), squeeze=False)
    for row, ((task, variant), g) in zip(axes, groups.items(), strict=True):
        seeds = sorted(g["seeds"], key=lambda s: s["seed"])
        ids = np.arange(len(seeds))
        for j, (key, unit) in enumerate(
            (("position_error_mm", "mm"), ("orientation_error_deg", "deg"))
        ):
            ax = row[j]
            if key not in seeds[0]:
                ax.set_axis_off()
                continue
            for k, axis in enumerate("xyz"):
                ax.bar(ids + (k - 1) * 0.27, [s[key]["mean"][k] for s in seeds], 0.27, label=axis)
            ax.set_xticks(ids, [str(s["seed"]) for s in seeds])
            ax.set_xlabel("seed")
            ax.set_ylabel(f"mean error ({unit}), 1,000 poses")
            ax.set_title(f"{task}\n...{variant[-60:]}", fontsize=8)
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("studies", nargs="+", type=Path, help="random_target_study.py JSON files")
    p.add_argument("--out", type=Path, required=True, help="prefix of OUT.md and OUT.png")
    args = p.parse_args(argv)
    for path in args.studies:
        if not path.is_file():
            p.error(f"no such study file: {path}")
    groups = load(args.studies)
    text = "\n".join(table(t, v, g) for (t, v), g in groups.items())
    cmd = "python benchmarks/random_target_summary.py " + " ".join(map(str, args.studies))
    args.out.with_suffix(".md").write_text(f"<!-- written by: {cmd} --out {args.out} -->\n\n{text}")
    figure(groups, args.out.with_suffix(".png"))
    print(text)


if __name__ == "__main__":
    main()
