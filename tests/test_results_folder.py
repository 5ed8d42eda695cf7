"""benchmarks/results/ stays small and every file in it is accounted for: its README
names each file (or a folder holding it, or a `name.{json,md,png}` group), with the
command that made it."""

from __future__ import annotations

import itertools
import re
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
LIMIT_BYTES = 10_000_000


def _expand_braces(text: str) -> str:
    """`a/{b,c}.{json,md}` -> also every expansion, so a grouped name counts as listed."""
    extra = []
    for match in re.finditer(r"[\w./-]*\{[^}\s]+\}[\w./{},-]*", text):
        parts = re.split(r"(\{[^}]*\})", match.group(0))
        options = [p[1:-1].split(",") if p.startswith("{") else [p] for p in parts]
        extra += ["".join(c) for c in itertools.product(*options)]
    return text + "\n" + "\n".join(extra)


def test_results_are_under_10_mb():
    total = sum(p.stat().st_size for p in RESULTS.rglob("*") if p.is_file())
    assert total < LIMIT_BYTES, f"benchmarks/results/ holds {total / 1e6:.2f} MB"


def test_every_result_file_is_listed_in_the_readme():
    listed = _expand_braces((RESULTS / "README.md").read_text())
    missing = []
    for path in sorted(RESULTS.rglob("*")):
        if not path.is_file() or path == RESULTS / "README.md":
            continue
        rel = path.relative_to(RESULTS)
        names = [str(rel), path.name] + [f"{p}/" for p in rel.parents if str(p) != "."]
        if not any(name in listed for name in names):
            missing.append(str(rel))
    assert not missing, f"name these in benchmarks/results/README.md: {missing}"


def test_the_check_finds_an_unlisted_name():
    assert "x/b.md" in _expand_braces("`x/{a,b}.{json,md}`")
    assert "zz_unlisted.json" not in _expand_braces("`x/{a,b}.{json,md}`")
