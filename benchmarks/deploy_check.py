"""Does the exported file act as the checkpoint does (issue 32's done-when)? For each
trained seed: export it (`python -m mara_mjx.export SEED policy.onnx`), then run the
paper's evaluation on the checkpoint and on the file (`python -m mara_mjx.evaluate`, the
same episodes), and compare the reached count and the per-axis means.

    python benchmarks/deploy_check.py --out benchmarks/results/deploy/NAME \
        --label "MARACollisionOrient, orient_first" RUN/seed_1000 RUN/seed_1001 ...
        [--episodes 10] [--seed 1000] [--deployed="--plan_starts 8"] [-- EXTRA EVALUATE FLAGS]

--deployed: deployed-only overrides (`--plan_steps`, `--plan_starts`, `--commit_rad`)
given to the export and to the checkpoint's evaluation alike, so that both run the
policy a checkpoint trained with them would deploy (e.g. a preset's `plan_starts` on a
run trained before the preset set it).

Writes <out>/deploy_check.json (per seed: the two reports' rows, the differences, the
export's self-check and timings; the commands) and <out>/deploy_check.md (the table).
Every command runs as the user would run it, in its own process, on this machine's CPU.
Files of those names in <out> are replaced only when an earlier check wrote them (or with
--overwrite): a user's file, a checkpoint or a run folder's file is refused before
anything runs.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mara_mjx.cli.common import UserError
from mara_mjx.runtime import files, outputs, runs

OUTPUTS = ("deploy_check.json", "deploy_check.md")
TOL_MM, TOL_DEG = 0.01, 0.01


def run(argv: list[str]) -> float:
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}")
    return time.perf_counter() - start


def summary(report: Path) -> dict:
    data = json.loads(report.read_text())
    ev = data.get("summary") or data.get("eval", {}).get("summary") or data
    # a random-target report holds its poses to the horizon (tolerance 0) and counts none
    # reached: its "reached" is the poses within 5 mm (no orientation on position tasks)
    if "poses" in ev:
        reached = round(ev["within_mm"]["5"] * ev["poses"])
    else:
        reached = ev["reached_tolerance"]
    return {
        "reached": reached,
        "episodes": ev["episodes"] if "episodes" in ev else ev["poses"],
        "position_mm": ev["position_error_mm"]["mean"],
        "orientation_deg": ev.get("orientation_error_deg", {}).get("mean", []),
        "collisions": ev["collisions"],
    }


def check_cell(check: dict) -> str:
    """The self-check column: a traced graph's difference and reference, or none (the
    hand-written graph of a joint-space policy has no self-check)."""
    if not check:
        return "- (hand-written graph)"
    return f"{check['max_abs_diff']:.1e} {check.get('reference', 'jit')}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("seeds", nargs="+", type=Path, help="run folders (one per seed)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--label", required=True)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--deployed", default="",
                        help="deployed-only overrides for the export and the checkpoint's "
                        "evaluation, one string")  # fmt: skip
    parser.add_argument("--overwrite", action="store_true",
                        help="replace deploy_check.* in --out that no check wrote")  # fmt: skip
    argv = sys.argv[1:]
    cut = argv.index("--") if "--" in argv else len(argv)
    args, extra = parser.parse_args(argv[:cut]), argv[cut + 1 :]  # after --: evaluate's
    try:
        outputs.check_output_folder(
            args.out,
            OUTPUTS,
            "--out",
            lambda: outputs.written_by(args.out / OUTPUTS[0], "python benchmarks/deploy_check.py"),
            args.overwrite,
        )
    except UserError as e:
        parser.error(str(e))
    py = [sys.executable, "-m"]
    flags = ["--episodes", str(args.episodes), "--seed", str(args.seed), *extra]
    deployed = shlex.split(args.deployed)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for folder in args.seeds:
            work = Path(tmp) / folder.name
            work.mkdir()
            onnx = work / "policy.onnx"
            t_export = run([*py, "mara_mjx.export", str(folder), str(onnx), *deployed])
            t_ckpt = run([*py, "mara_mjx.evaluate", str(folder), *flags, *deployed,
                          "--json", str(work / "ckpt.json")])  # fmt: skip
            t_file = run([*py, "mara_mjx.evaluate", str(onnx), *flags,
                          "--json", str(work / "onnx.json")])  # fmt: skip
            a, b = summary(work / "ckpt.json"), summary(work / "onnx.json")
            d_mm = max(abs(x - y) for x, y in zip(a["position_mm"], b["position_mm"], strict=True))
            pairs = zip(a["orientation_deg"], b["orientation_deg"], strict=True)
            d_deg = max((abs(x - y) for x, y in pairs), default=0.0)
            import onnx as onnx_lib

            props = {p.key: p.value for p in onnx_lib.load(str(onnx)).metadata_props}
            check = json.loads(props["mara_mjx"]).get("self_check")
            ok = a["reached"] == b["reached"] and d_mm <= TOL_MM and d_deg <= TOL_DEG
            rows.append({
                "seed_folder": str(folder), "checkpoint": a, "onnx": b, "max_diff_mm": d_mm,
                "max_diff_deg": d_deg, "match": ok, "self_check": check,
                "seconds": {"export": t_export, "evaluate_checkpoint": t_ckpt,
                            "evaluate_onnx": t_file},
            })  # fmt: skip
            print(f"{folder}: reached {a['reached']} / {b['reached']}, max diff {d_mm:.2e} mm "
                  f"{d_deg:.2e} deg, {'match' if ok else 'MISMATCH'}", flush=True)  # fmt: skip
    import jax
    import onnxruntime

    record = {
        "label": args.label,
        "command": " ".join(["python", "benchmarks/deploy_check.py", *sys.argv[1:]]),
        "per_seed_commands": [
            " ".join(["python -m mara_mjx.export SEED policy.onnx", *deployed]),
            " ".join(["python -m mara_mjx.evaluate SEED", *flags, *deployed, "--json ckpt.json"]),
            f"python -m mara_mjx.evaluate policy.onnx {' '.join(flags)} --json onnx.json",
        ],
        "tolerance": {"mm": TOL_MM, "deg": TOL_DEG},
        "machine": platform.platform(),
        "versions": {"jax": jax.__version__, "onnxruntime": onnxruntime.__version__},
        "git_commit": runs.git_commit(),
        "seeds": rows,
        "matched": sum(r["match"] for r in rows),
    }
    files.write_atomic(args.out / OUTPUTS[0], json.dumps(record, indent=1))
    lines = [
        f"# {args.label}: the exported .onnx against its checkpoint, same episodes",
        "",
        f"`{record['command']}` ({record['machine']}, CPU; jax {jax.__version__}, "
        f"onnxruntime {onnxruntime.__version__}). Per seed: export, then `evaluate` on the "
        "checkpoint and on the file.",
        "",
        "| seed | reached (ckpt / onnx; random targets: poses within 5 mm) | "
        "position mean ckpt (mm) | max diff (mm / deg) | "
        "collisions (ckpt / onnx) | self-check (rad, ref) | match |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        a, b, c = r["checkpoint"], r["onnx"], r["self_check"] or {}
        pos = " / ".join(f"{x:.2f}" for x in a["position_mm"])
        lines.append(
            f"| {Path(r['seed_folder']).name} | {a['reached']} / {b['reached']} | {pos} | "
            f"{r['max_diff_mm']:.1e} / {r['max_diff_deg']:.1e} | {a['collisions']} / "
            f"{b['collisions']} | {check_cell(c)} | {'yes' if r['match'] else 'NO'} |"
        )
    lines += ["", f"{record['matched']} of {len(rows)} seeds match (same reached count, "
              f"per-axis means within {TOL_MM} mm / {TOL_DEG} deg)."]  # fmt: skip
    files.write_atomic(args.out / OUTPUTS[1], "\n".join(lines) + "\n")
    print(f"wrote {args.out / 'deploy_check.json'}, {args.out / 'deploy_check.md'}")


if __name__ == "__main__":
    main()
