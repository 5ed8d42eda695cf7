"""The exported file in the loop on the real driver, swept (issue 32, item 3): how much
sensor latency and encoder miscalibration an exported policy stands.

    python benchmarks/deploy_sweep.py --out benchmarks/results/deploy/NAME \
        --label "MARACollisionOrientRandomTarget, ..." policy_1000.onnx policy_1001.onnx \
        [--velocities 0.3 0.5] [--latencies 0 1 2 3] [--calibrations 0 0.001 0.002 0.004] \
        [--episodes 1000] [--seed 1000] [-- EXTRA EVALUATE FLAGS]
    python benchmarks/deploy_sweep.py --merge --out OUT --label "..." SWEEP_FOLDER...

For each file and servo speed, `python -m mara_mjx.evaluate FILE --driver real --velocity
V --randomize --tolerance_mm 0 --episodes N --seed S` (every episode to the horizon, each
its own physics draw and, on a random-target task, its own held-out pose), as a user runs
it, once with the randomisation's defaults (the "randomised" row), then with the sensor
latency fixed at each of `--latencies` steps (`--latency_steps L L`), then with the joint
zero offsets drawn within each of `--calibrations` rad (`--calibration_offset C`), the
other parameters randomised as by default. Per cell, from the report's episodes: the
fractions within 5 mm and 2 deg and within 1 mm and 1 deg (degrees only on tasks with an
orientation), per-axis mean, p95 and worst (mm; deg), and the fraction of episodes with a
collision. Writes <out>/deploy_sweep.json (every cell, the commands, versions),
<out>/deploy_sweep.md (the table) and <out>/deploy_sweep.png (within 5 mm against latency
and calibration, one line per file and speed). The JSON and the table are rewritten after
every cell ("complete": false until the last), so a sweep cut off keeps what ran. Files of
that name in <out> are replaced only when they are an earlier sweep's (or with
--overwrite): a user's file, a checkpoint or a run folder's file there is refused before
anything runs. `--merge` writes the rows of complete sweeps (e.g. one cell each, run one
per CPU core: benchmarks/gpu/lib.sh's `cells`) as one sweep, each row with its command.
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

from mara_mjx.cli.common import UserError, parse_bool
from mara_mjx.runtime import files, outputs


def cells(args: argparse.Namespace) -> list[tuple[str, list[str]]]:
    """(name, evaluate flags) of every sweep cell but the speed."""
    out = [("randomised", [])] if args.randomised else []
    out += [(f"latency {k}", ["--latency_steps", str(k), str(k)]) for k in args.latencies]
    out += [(f"calibration {c:g} rad", ["--calibration_offset", str(c)]) for c in args.calibrations]
    return out


def metrics(report: dict) -> dict:
    """The cell's numbers from an evaluate report's episodes (module docstring), as the
    robustness study summarises episodes (`bench.robustness_judge.pose_summary`)."""
    from types import SimpleNamespace

    from mara_mjx.bench.robustness_judge import pose_summary

    episodes = report["episodes"]
    orientation = "Orient" in report["env_name"]  # the tasks with an orientation target
    result = SimpleNamespace(
        position_error_mm=[e["position_error_mm"] for e in episodes],
        orientation_error_deg=[e["orientation_error_deg"] for e in episodes]
        if orientation
        else None,
        collisions=[e["collisions"] for e in episodes],
    )
    s = pose_summary(result, orientation)
    suffix = ("_2deg", "_1deg") if orientation else ("", "")
    out = {"episodes": len(episodes),
           f"within_5mm{suffix[0]}": s["within_5mm_2deg"] if orientation else s["within_5"],
           f"within_1mm{suffix[1]}": s["within_1"]}  # fmt: skip
    for name in ("position_mm", "orientation_deg") if orientation else ("position_mm",):
        stats = s[name]
        out[name] = {"mean": stats["mean"], "p95": stats["p95"], "worst": stats["max"]}
    out["colliding"] = s["episodes_colliding"]
    return out


def evaluate(policy: str, velocity: float, flags: list[str], args, tmp: Path) -> tuple:
    report = tmp / "report.json"
    argv = [sys.executable, "-m", "mara_mjx.evaluate", policy, "--driver", "real",
            "--velocity", str(velocity), "--randomize", "--tolerance_mm", "0",
            "--episodes", str(args.episodes), "--seed", str(args.seed), *flags, *args.extra,
            "--json", str(report), "--overwrite"]  # fmt: skip
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}")
    data = json.loads(report.read_text())
    command = "python " + " ".join(argv[1:-3])  # without the temporary --json
    return command, time.perf_counter() - start, data


def table(rows: list[dict], orientation: bool) -> str:
    bar5, bar1 = ("5 mm / 2 deg", "1 mm / 1 deg") if orientation else ("5 mm", "1 mm")
    head = ["policy", "rad/s", "condition", f"within {bar5}", f"within {bar1}",
            "position mean (mm)", "p95", "worst", "colliding"]  # fmt: skip
    if orientation:
        head[-1:-1] = ["orientation mean (deg)", "worst (deg)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def axes(x):
        return " / ".join(f"{v:.2f}" for v in x)

    for r in rows:
        m = r["metrics"]
        k5, k1 = (k for k in m if k.startswith("within_"))
        cells_ = [Path(r["policy"]).name, f"{r['velocity']:g}", r["condition"],
                  f"{100 * m[k5]:.1f}%", f"{100 * m[k1]:.1f}%", axes(m["position_mm"]["mean"]),
                  axes(m["position_mm"]["p95"]), axes(m["position_mm"]["worst"])]  # fmt: skip
        if orientation:
            cells_ += [axes(m["orientation_deg"]["mean"]), axes(m["orientation_deg"]["worst"])]
        cells_.append(f"{100 * m['colliding']:.1f}%")
        lines.append("| " + " | ".join(cells_) + " |")
    return "\n".join(lines)


def figure(path: Path, rows: list[dict], label: str) -> None:
    """Within 5 mm (solid) and within 1 mm (dashed; and deg on an orientation task)
    against latency and against calibration, one line per file and speed, and the
    randomised-default cells one dot per file and speed; panels without cells left out."""
    import textwrap

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def within(r, bar):
        return 100 * next(v for k, v in r["metrics"].items() if k.startswith(f"within_{bar}"))

    panels = [p for p in ("latency", "calibration", "randomised")
              if any(r["condition"].startswith(p) for r in rows)]  # fmt: skip
    width = max(7.0, 4.5 * len(panels))
    fig, axes = plt.subplots(1, len(panels), figsize=(width, 4.6), sharey=True, squeeze=False)
    keys = list(dict.fromkeys((r["policy"], r["velocity"]) for r in rows))
    for ax, panel in zip(axes[0], panels, strict=True):
        if panel == "randomised":
            speeds = sorted({r["velocity"] for r in rows if r["condition"] == panel})
            for v, marker in zip(speeds, "osD^v<>", strict=False):
                mine = [r for r in rows if r["condition"] == panel and r["velocity"] == v]
                names = [Path(r["policy"]).stem.replace("policy_", "") for r in mine]
                for bar, fill in ((5, marker), (1, "x")):
                    ax.plot(names, [within(r, bar) for r in mine], fill, linestyle="",
                            label=f"{v:g} rad/s, within {bar} mm")  # fmt: skip
            ax.set(xlabel="file (randomised defaults)")
            ax.tick_params(axis="x", labelrotation=60, labelsize=7)
        else:
            for policy, v in keys:
                mine = [r for r in rows if (r["policy"], r["velocity"]) == (policy, v)
                        and r["condition"].startswith(panel)]  # fmt: skip
                if not mine:
                    continue
                scale = 1000 if panel == "calibration" else 1
                mine.sort(key=lambda r: float(r["condition"].split()[1]))
                x = [float(r["condition"].split()[1]) * scale for r in mine]
                name = f"{Path(policy).stem}, {v:g} rad/s"
                (line,) = ax.plot(x, [within(r, 5) for r in mine], "o-", label=name)
                ax.plot(x, [within(r, 1) for r in mine], "o--", color=line.get_color())
            ax.set(xlabel="sensor latency (control steps)" if panel == "latency"
                   else "joint zero offset half-width (mrad)")  # fmt: skip
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    axes[0][0].set(ylabel="episodes within 5 mm / within 1 mm (%)")
    fig.suptitle("\n".join(textwrap.wrap(label, int(width * 12))), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def merge(args: argparse.Namespace, this: str) -> int:
    """--merge: the rows of complete sweeps of one task (one folder each, e.g. one cell
    per machine core) written as one sweep into --out, each row keeping its own command;
    the parts' commands, platforms and versions listed in the JSON's "parts"."""
    rows, parts, seen = [], [], set()
    for folder in args.policies:
        path = Path(folder).resolve()
        data = outputs.read_json(path / OUTPUTS[0])
        if path in seen:
            raise SystemExit(f"--merge: {folder} is given twice")
        if not isinstance(data, dict) or not data.get("complete") or not data.get("rows"):
            what = "no deploy_sweep.json" if data is None else "an incomplete deploy_sweep.json"
            raise SystemExit(f"--merge: {folder} holds {what}")
        seen.add(path)
        rows += data["rows"]
        # a merged sweep brings its own parts (merged again, the list stays flat)
        own = {k: data.get(k) for k in ("command", "platform", "versions")}
        parts += data.get("parts") or [own]
    tasks = sorted({r["env_name"] for r in rows})
    if len(tasks) > 1:
        raise SystemExit(f"--merge: the sweeps are of several tasks ({', '.join(tasks)})")
    same = all(p["versions"] == parts[0]["versions"] for p in parts)
    versions = parts[0]["versions"] if same else "per part (the JSON's parts)"
    text = record(args, this, rows, versions, complete=True, parts=parts)
    figure(args.out / "deploy_sweep.png", rows, args.label)
    print(text)
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "policies", nargs="+", help="exported files (.onnx or .npz); with --merge, sweep folders"
    )
    parser.add_argument(
        "--merge",
        action="store_true",
        help="write the rows of the complete sweeps in the folders given as one sweep into --out",
    )
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--label", default="")
    parser.add_argument("--velocities", type=float, nargs="+", default=[0.3, 0.5])
    parser.add_argument("--latencies", type=int, nargs="*", default=[0, 1, 2, 3])
    parser.add_argument("--calibrations", type=float, nargs="*",
                        default=[0.0, 0.001, 0.002, 0.004])  # fmt: skip
    parser.add_argument("--randomised", type=parse_bool, default=True, metavar="{true,false}",
                        help="run the plain randomised cell too (default: true)")  # fmt: skip
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--overwrite", action="store_true",
                        help="replace deploy_sweep.* in --out that no sweep wrote")  # fmt: skip
    args = parser.parse_args(argv[: argv.index("--")] if "--" in argv else argv)
    args.extra = extra
    this = "python benchmarks/deploy_sweep.py " + shlex.join(argv)
    try:
        outputs.check_output_folder(
            args.out,
            OUTPUTS,
            "--out",
            lambda: outputs.written_by(args.out / OUTPUTS[0], "python benchmarks/deploy_sweep.py"),
            args.overwrite,
        )
    except UserError as e:
        parser.error(str(e))
    if args.merge:
        return merge(args, this)
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        for policy in args.policies:
            for v in args.velocities:
                for name, flags in cells(args):
                    command, seconds, report = evaluate(policy, v, flags, args, Path(tmp))
                    row = {"policy": policy, "velocity": v, "condition": name,
                           "command": command, "seconds": round(seconds, 1),
                           "env_name": report["env_name"], "metrics": metrics(report)}  # fmt: skip
                    rows.append(row)
                    print(f"{Path(policy).name} {v:g} rad/s {name}: {row['metrics']}", flush=True)
                    record(args, this, rows, report.get("versions"), complete=False)
    text = record(args, this, rows, report.get("versions"), complete=True)
    figure(args.out / "deploy_sweep.png", rows, args.label)
    print(text)
    return 0


OUTPUTS = ("deploy_sweep.json", "deploy_sweep.md", "deploy_sweep.png")


def record(args, this: str, rows: list[dict], versions, complete: bool, parts=None) -> str:
    """Writes the JSON and the table of the cells so far; returns the table."""
    text = table(rows, "orientation_deg" in rows[0]["metrics"])
    state = "" if complete else f" Incomplete: {len(rows)} cells so far."
    commands = "".join(f"\n- `{c}`" for c in dict.fromkeys(r["command"] for r in rows))
    where = ("merged here: " if parts else "") + platform.platform()
    head = (f"# {args.label}\n\n`{this}` ({where}; an .onnx file runs in onnxruntime on one "
            f"CPU thread, an .npz in numpy, the simulator on evaluate's JAX backend; "
            f"evaluate's versions: {versions}). Every episode to the horizon, on the real "
            f"driver with randomised physics; each condition changes one randomised "
            f"parameter.{state}\n\nEach row's command:{commands}\n")  # fmt: skip
    files.write_atomic(args.out / "deploy_sweep.json", json.dumps(
        {"command": this, "label": args.label, "platform": platform.platform(),
         "versions": versions, "complete": complete, "rows": rows,
         **({"parts": parts} if parts else {})}, indent=1))  # fmt: skip
    files.write_atomic(args.out / "deploy_sweep.md", head + "\n" + text + "\n")
    return text


if __name__ == "__main__":
    sys.exit(main())
