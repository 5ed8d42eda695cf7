"""Does a random-target policy do on the servos what it does on the train driver? (issue
32; benchmarks/NOTES.md section 43). A CPU screen: for each seed folder, the same
held-out poses (evaluation seed, --poses of them) judged on the train driver and on the
real driver with randomised physics at each --velocities, the deployed policy with the
plan (EvalConfig.plan_steps) re-asked at every step (commit_rad 0) and holding each
command until the arm arrives or stops (commit_rad > 0). Each judgement is the package's
evaluation (`ppo.evaluation.make_evaluate`, compiled once per driver, speed and rule),
every episode to the horizon.

    python benchmarks/commit_screen.py RUN/seed_1164 RUN/seed_1165 ... --out DIR \
        [--poses 128] [--seed 1000] [--velocities 0.3] [--plan_steps 16] [--commit_rad 0.01]
        [--train_driver false]

Writes DIR/commit_screen.json (per seed and judgement: within 5 mm and 2 deg, within 1 mm
and 1 deg, episodes colliding; the commands, versions) and DIR/commit_screen.md, both
after every seed (a screen cut off keeps what ran), and DIR/commit_screen.png (within 5 mm
and 2 deg per seed, one marker per judgement) at the end. Files of those names in DIR are
replaced only when an earlier screen wrote them (or with --overwrite).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from mara_mjx.cli.common import UserError, parse_bool
from mara_mjx.runtime import files, outputs

OUTPUTS = ("commit_screen.json", "commit_screen.md", "commit_screen.png")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("seeds", nargs="+", type=Path, help="seed run folders (one task)")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--poses", type=int, default=128)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--velocities", type=float, nargs="+", default=[0.3])
    parser.add_argument("--plan_steps", type=int, default=16)
    parser.add_argument("--commit_rad", type=float, default=0.01)
    parser.add_argument("--train_driver", type=parse_bool, default=True, metavar="{true,false}",
                        help="judge on the train driver too (default: true)")  # fmt: skip
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)
    try:
        outputs.check_output_folder(
            args.out,
            OUTPUTS,
            "--out",
            lambda: outputs.written_by(args.out / OUTPUTS[0], "python benchmarks/commit_screen.py"),
            args.overwrite,
        )
    except UserError as e:
        parser.error(str(e))

    import jax

    from mara_mjx.bench.robustness_judge import held_out_params, pose_summary
    from mara_mjx.ppo import checkpoint as ckpt
    from mara_mjx.ppo.config import EvalConfig
    from mara_mjx.ppo.evaluation import EvalResult, make_evaluate
    from mara_mjx.ppo.policy import policy_from_checkpoint
    from mara_mjx.runtime import runs

    loaded = [ckpt.load_checkpoint(ckpt.find_checkpoint(f)) for f in args.seeds]
    meta = loaded[0][1]
    base = EvalConfig(episodes=args.poses, seed=args.seed, tolerance_mm=0.0,
                      plan_steps=args.plan_steps)  # fmt: skip
    judgements = [("train", None, 0.0)] if args.train_driver else []
    judgements += [(f"real {v:g}", v, c) for v in args.velocities for c in (0.0, args.commit_rad)]
    programs = {}
    for name, v, commit in judgements:
        env = (runs.make_env(meta) if v is None
               else runs.make_env(meta, driver="real", velocity=v, randomize=True))  # fmt: skip
        config = base.replace(commit_rad=commit)
        params, poses = held_out_params(env, config)
        programs[(name, commit)] = (make_evaluate(env, config, params), poses)
    this = "python benchmarks/commit_screen.py " + " ".join(argv)
    provenance = runs.provenance()  # the versions and the git commit, as every run records
    rows = []
    for folder, (arrays, m) in zip(args.seeds, loaded, strict=True):
        policy = policy_from_checkpoint(arrays, m)
        row = {"seed_folder": str(folder), "judged": {}}
        for (name, commit), (fn, poses) in programs.items():
            start = time.perf_counter()
            out = jax.device_get(fn(policy))
            r = EvalResult(**{k: np.asarray(x) for k, x in out.items()})
            s = pose_summary(r, True, poses)
            key = name if name == "train" else f"{name} commit {commit:g}"
            row["judged"][key] = {
                "within_5mm_2deg": s["within_5mm_2deg"],
                "within_1mm_1deg": s["within_1"],
                "colliding": s["episodes_colliding"],
                "seconds": round(time.perf_counter() - start, 1),
            }
            print(f"{folder.name} {key}: {row['judged'][key]}", flush=True)
        rows.append(row)
        write(args, this, rows, provenance)
    figure(args.out / OUTPUTS[2], rows)
    print((args.out / OUTPUTS[1]).read_text())
    return 0


def write(args, this: str, rows: list[dict], provenance: dict) -> None:
    versions = provenance["versions"]
    keys = list(rows[0]["judged"])
    head = ["seed", *(f"{k}: 5 mm 2 deg / 1 mm 1 deg / colliding" for k in keys)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [Path(r["seed_folder"]).name]
        for k in keys:
            j = r["judged"][k]
            cells.append(f"{100 * j['within_5mm_2deg']:.1f}% / {100 * j['within_1mm_1deg']:.1f}%"
                         f" / {100 * j['colliding']:.1f}%")  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    text = (f"# The plan on the servos, re-asked or held, against the train driver\n\n`{this}` "
            f"({platform.platform()}, CPU; jax {versions['jax']}, "
            f"mara_mjx {versions['mara_mjx']}). "
            f"{args.poses} held-out poses (evaluation seed {args.seed}); the real driver with "
            "randomised physics; every episode to the horizon.\n\n"
            + "\n".join(lines) + "\n")  # fmt: skip
    files.write_atomic(args.out / OUTPUTS[1], text)
    record = {
        "command": this, "platform": platform.platform(), "jax": versions["jax"],
        "mara_mjx": versions["mara_mjx"], **provenance, "poses": args.poses, "seed": args.seed,
        "rows": rows,
    }  # fmt: skip
    files.write_atomic(args.out / OUTPUTS[0], json.dumps(record, indent=1))


def figure(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 3.5))
    seeds = [Path(r["seed_folder"]).name.removeprefix("seed_") for r in rows]
    for i, key in enumerate(rows[0]["judged"]):
        y = [100 * r["judged"][key]["within_5mm_2deg"] for r in rows]
        ax.plot(np.arange(len(rows)) + 0.12 * (i - 1), y, "o", label=key, alpha=0.8)
    ax.axhline(99, color="grey", lw=0.8, ls="--")
    ax.set_xticks(range(len(rows)), seeds, rotation=90, fontsize=7)
    ax.set(ylabel="poses within 5 mm and 2 deg (%)", xlabel="seed")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)


if __name__ == "__main__":
    sys.exit(main())
