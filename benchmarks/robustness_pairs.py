"""Two robustness studies of the same training seeds judged two ways (e.g. as trained and
with a deployed-only override such as `--plan_starts 8`, the second reusing the first's
--work_dir) side by side, one row per seed: the random-target judgement (held-out poses
within 1 mm and 1 deg, episodes colliding) and, where the studies have them, the real
driver's (within 5 mm and 2 deg, colliding) per servo speed; each cell "A -> B"; the
seeds of B that miss issue 32's bars (>= 99% within, <= 0.5% colliding) named.

    python benchmarks/robustness_pairs.py A B [--label_a "as trained"] [--label_b ...]

A and B: folders of `python -m mara_mjx.benchmark robustness` (robustness.json or
robustness.json.gz). Prints markdown; refuses studies whose seeds differ.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # (a sibling script's reader)
from robustness_merge import read_part  # noqa: E402

WITHIN, COLLIDING = 0.99, 0.005


def seeds(folder: Path) -> tuple[dict[int, list[float]], list[str]]:
    """({seed: [within_1, colliding, (real within_5mm_2deg, colliding) per speed...]},
    the real driver's speeds)."""
    records = read_part(folder)["records"]  # (robustness_merge's reader and its checks)
    out, speeds = {}, []
    for r in records:
        if r["kind"] != "seed":
            continue
        row = [r["targets"]["within_1"], r["targets"]["episodes_colliding"]]
        speeds = sorted(r.get("real") or {}, key=float)
        for speed in speeds:
            row += [r["real"][speed]["within_5mm_2deg"], r["real"][speed]["episodes_colliding"]]
        out[r["seed"]] = row
    return out, speeds


def short(row: list[float]) -> bool:
    """Does a seed's row miss a bar (within < 99% or colliding > 0.5%, any judgement)?"""
    return any(row[i] < WITHIN or row[i + 1] > COLLIDING for i in range(0, len(row), 2))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    p.add_argument("--label_a", default="as trained")
    p.add_argument("--label_b", default="override")
    args = p.parse_args(argv)
    (a, speeds), (b, _) = seeds(args.a), seeds(args.b)
    if set(a) != set(b) or not a:
        print(f"error: the studies judge different seeds: {sorted(a)} vs {sorted(b)}",
              file=sys.stderr)  # fmt: skip
        return 2
    heads = ["train driver: within 1 mm and 1 deg", "colliding"]
    for speed in speeds:
        heads += [f"servos {speed} rad/s: within 5 mm and 2 deg", "colliding"]
    print(f"Each cell: {args.label_a} -> {args.label_b}.\n")
    print("| seed | " + " | ".join(heads) + " |")
    print("|---" * (len(heads) + 1) + "|")
    for s in sorted(a):
        cells = [f"{100 * x:.1f} -> {100 * y:.1f}%" for x, y in zip(a[s], b[s], strict=True)]
        print(f"| {s} | " + " | ".join(cells) + " |")
    for label, rows in ((args.label_a, a), (args.label_b, b)):
        bad = [s for s in sorted(rows) if short(rows[s])]
        print(f"\n{label}: {len(bad)} of {len(rows)} seeds miss a bar"
              + (f" ({', '.join(map(str, bad))})" if bad else ""))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
