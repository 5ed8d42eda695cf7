"""Robustness studies run in parts (e.g. one per GPU of a host, each its own seed range)
written as one study: the seed rows of every part, the statistics over seeds
recomputed as the study computes them.

    python benchmarks/robustness_merge.py --out benchmarks/results/robustness/NAME PART...

Each PART is a folder of `python -m mara_mjx.benchmark robustness` (its robustness.json,
or robustness.json.gz as the results keep it). The parts must be complete studies of the
same tasks and recipes judged alike: every setting but the seed range, the output and
work folders (and --parallel) the same, or the merge is refused naming the settings that
differ; a seed judged in two parts, or a folder given twice, is refused too. Writes
<out>/robustness.json (the seed rows, the recomputed metric rows; "parts": each part's
command, device, versions, git commit and date), robustness.md and robustness.png, as
the study writes them; files of those names in <out> are replaced only when they are a
study's earlier output (or with --overwrite).
"""

from __future__ import annotations

import argparse
import gzip
import json
import shlex
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from mara_mjx.bench.robustness_report import summarise
from mara_mjx.bench.runner import recorded_study, write_results
from mara_mjx.cli.common import UserError
from mara_mjx.runtime import outputs

OUTPUTS = ("robustness.json", "robustness.md", "robustness.png")
PER_PART = ("seeds", "seed_offset", "out", "work_dir", "parallel", "overwrite")
"""Config keys a part may set on its own; every other setting must agree."""


def read_part(folder: Path) -> dict[str, Any]:
    """The study record in `folder` (robustness.json or .json.gz). SystemExit naming the
    problem when there is none or it is no complete robustness study."""
    for name in ("robustness.json", "robustness.json.gz"):
        path = folder / name
        if path.is_file():
            try:
                opener = gzip.open if name.endswith(".gz") else open
                with opener(path, "rt") as f:
                    data = json.load(f)
            except (OSError, ValueError) as e:
                raise SystemExit(f"robustness_merge: {path} is not readable JSON: {e}") from e
            if not isinstance(data, dict) or data.get("study") != "robustness":
                raise SystemExit(f"robustness_merge: {path} is not a robustness study's record")
            if not any(r.get("kind") == "seed" for r in data.get("records", [])):
                raise SystemExit(f"robustness_merge: {path} holds no judged seed")
            return data
    raise SystemExit(f"robustness_merge: {folder} holds no robustness.json(.gz)")


def merge(parts: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The merged records: every part's seed (and error) rows, then per task and recipe
    the metric rows over all their seeds. SystemExit when the parts differ in a setting
    other than PER_PART, or judge one seed twice."""
    shared = {k: v for k, v in parts[0]["config"].items() if k not in PER_PART}
    for part in parts[1:]:
        other = {k: v for k, v in part["config"].items() if k not in PER_PART}
        differ = sorted(k for k in shared.keys() | other.keys() if shared.get(k) != other.get(k))
        if differ:
            raise SystemExit(
                "robustness_merge: the parts were not judged alike; they differ in "
                + ", ".join(f"{k} ({shared.get(k)!r} vs {other.get(k)!r})" for k in differ)
            )
    rows, seen = [], {}
    for part in parts:
        for r in part["records"]:
            if r["kind"] == "metric":
                continue
            if r["kind"] == "seed":
                key = (r["task"], r["recipe"], r["seed"])
                if key in seen:
                    raise SystemExit(
                        f"robustness_merge: seed {r['seed']} of {r['task']} / {r['recipe']} "
                        f"is judged in two parts ({seen[key]} and {part['command']})"
                    )
                seen[key] = part["command"]
            rows.append(r)
    config = SimpleNamespace(bootstrap=shared["bootstrap"])
    records = []
    groups = sorted({(r["task"], r["recipe"]) for r in rows if r["kind"] == "seed"})
    for group in groups:
        mine = [r for r in rows if (r["task"], r["recipe"]) == group]
        seeds = sorted((r for r in mine if r["kind"] == "seed"), key=lambda r: r["seed"])
        errors = [r for r in mine if r["kind"] != "seed"]
        records += seeds + errors + summarise(seeds, config)
    return records


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("parts", nargs="+", type=Path, help="robustness study folders")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--overwrite", action="store_true",
                        help="replace robustness.* in --out that no study wrote")  # fmt: skip
    args = parser.parse_args(argv)
    try:
        outputs.check_output_folder(
            args.out, OUTPUTS, "--out",
            lambda: recorded_study(args.out / OUTPUTS[0], "robustness"), args.overwrite,
        )  # fmt: skip
    except UserError as e:
        parser.error(str(e))
    resolved = [p.resolve() for p in args.parts]
    twice = sorted({str(p) for p in resolved if resolved.count(p) > 1})
    if twice:
        parser.error(f"a part is given twice: {', '.join(twice)}")
    parts = [read_part(p) for p in args.parts]
    records = merge(parts)
    keys = ("command", "device", "versions", "git_commit", "date")
    same = {k: all(p.get(k) == parts[0].get(k) for p in parts) for k in ("device", "versions")}
    meta = {
        "study": "robustness",
        "command": "python benchmarks/robustness_merge.py " + shlex.join(argv),
        "versions": parts[0]["versions"] if same["versions"] else {
            "jax": "per part", "mujoco": "per part"},
        "device": parts[0]["device"] if same["device"] else {
            "device_kind": "per part (the JSON's parts)", "platform": "per part"},
        "config": {**parts[0]["config"], "seeds": sum(p["config"]["seeds"] for p in parts),
                   "seed_offset": None, "out": str(args.out)},
        "parts": [{k: p.get(k) for k in keys} for p in parts],
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }  # fmt: skip
    paths = write_results("robustness", records, args.out, meta)
    print(paths[1].read_text())
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
