"""The `robustness` study's statistics across seeds and its output
(`mara_mjx.bench.robustness`): per task, recipe and metric the mean, the median, the
interquartile mean (IQM) with its 95% percentile-bootstrap interval over seeds and the
worst seed; the console lines, the markdown table's spec, notes and the figure.

`summarise` turns one job's seed records (`robustness_judge`'s rows, with "failed") into
one metric record per metric present (`metrics_for`: `METRICS`, and `REAL_METRICS` per
velocity); `TABLE` is the study's table spec for `bench.runner` (one row per metric
record; `notes` names the failed seeds and the train commands; `plot` draws one dot per
seed). `config` is the study's `RobustnessConfig` (typed `Any` here: that module imports
this one).
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any

import numpy as np


# ------------------------------------------------------------------ statistics
def iqm(x: np.ndarray) -> float:
    """Interquartile mean: the mean of the middle 50% (scipy's trim_mean, 25% each side)."""
    from scipy.stats import trim_mean

    return float(trim_mean(np.asarray(x, np.float64), 0.25))


def iqm_interval(x: np.ndarray, resamples: int, seed: int = 0) -> tuple[float, float]:
    """95% percentile-bootstrap interval of the IQM over seeds (resampled with
    replacement)."""
    from scipy.stats import trim_mean

    x = np.asarray(x, np.float64)
    rng = np.random.default_rng(seed)
    samples = x[rng.integers(0, len(x), size=(resamples, len(x)))]
    stats = trim_mean(samples, 0.25, axis=1)
    return float(np.percentile(stats, 2.5)), float(np.percentile(stats, 97.5))


METRICS: tuple[tuple[str, tuple[str, ...], str, bool], ...] = (
    # (name, path into a seed row, unit, larger is worse)
    ("paper position", ("paper", "position_mm"), "mm", True),
    ("paper orientation", ("paper", "orientation_deg"), "deg", True),
    ("hold position", ("hold", "position_mm"), "mm", True),
    ("hold orientation", ("hold", "orientation_deg"), "deg", True),
    ("hold collisions/episode", ("hold", "collisions_per_episode"), "", True),
    ("poses within 5 mm(/deg)", ("targets", "within_5"), "fraction", False),
    ("poses within 1 mm(/deg)", ("targets", "within_1"), "fraction", False),
    ("poses position mean", ("targets", "position_mm", "mean"), "mm", True),
    ("poses orientation mean", ("targets", "orientation_deg", "mean"), "deg", True),
    ("poses colliding", ("targets", "episodes_colliding"), "fraction", True),
)
REAL_METRICS = (
    ("within 5 mm(/deg)", ("within_5",), "fraction", False),
    ("within 5 mm and 2 deg", ("within_5mm_2deg",), "fraction", False),
    ("within 1 mm(/deg)", ("within_1",), "fraction", False),
    ("position mean", ("position_mm", "mean"), "mm", True),
    ("colliding", ("episodes_colliding",), "fraction", True),
)


def metrics_for(rows: list[dict[str, Any]]) -> list[tuple[str, tuple[str, ...], str, bool]]:
    """The metrics present in these seed rows (the real ones per velocity)."""
    out = [m for m in METRICS if _get(rows[0], m[1]) is not None]
    for v in rows[0].get("real", {}):
        out += [(f"real {v} rad/s {n}", ("real", v, *p), u, w) for n, p, u, w in REAL_METRICS]
    return out


def _get(row: Any, path: tuple[str, ...]) -> Any:
    for part in path:
        if not isinstance(row, dict) or part not in row:
            return None
        row = row[part]
    return row


def summarise(rows: list[dict[str, Any]], config: Any) -> list[dict[str, Any]]:
    """One record per metric: per axis (or the scalar) mean, median, IQM and its interval
    over seeds, and the worst seed."""
    records = []
    seeds = [r["seed"] for r in rows]
    for name, path, unit, larger_worse in metrics_for(rows):
        values = np.array([_get(r, path) for r in rows], np.float64)  # (seeds,) or (seeds, 3)
        per_axis = values.reshape(len(rows), -1)
        axes = [iqm_interval(per_axis[:, k], config.bootstrap) for k in range(per_axis.shape[1])]
        score = per_axis.max(1) if larger_worse else -per_axis.min(1)
        worst = int(np.argmax(score))
        records.append({
            "kind": "metric", "task": rows[0]["task"], "recipe": rows[0]["recipe"],
            "metric": name, "unit": unit, "path": ".".join(path), "seeds": len(rows),
            "failed_seeds": [r["seed"] for r in rows if r["failed"]],
            "mean": per_axis.mean(0).tolist(), "median": np.median(per_axis, 0).tolist(),
            "iqm": [iqm(per_axis[:, k]) for k in range(per_axis.shape[1])],
            "iqm_ci95": axes, "worst_seed": seeds[worst], "worst": per_axis[worst].tolist(),
        })  # fmt: skip
    return records


# ------------------------------------------------------------------ reporting
def _fmt(values: Any, digits: int = 2) -> str:
    values = values if isinstance(values, list) else [values]
    return " / ".join(f"{v:.{digits}f}" if v is not None and math.isfinite(v) else "-"
                      for v in values)  # fmt: skip


def _iqm_cell(r: dict[str, Any]) -> str:
    return " / ".join(
        f"{m:.2f} [{lo:.2f}, {hi:.2f}]" for m, (lo, hi) in zip(r["iqm"], r["iqm_ci95"], strict=True)
    )


def _metric_rows(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in records if r["kind"] == "metric"]


def notes(records: list[dict[str, Any]]) -> list[str]:
    lines = ["Per axis x / y / z (roll / pitch / yaw); IQM with its 95% bootstrap interval "
             "over seeds. Failed seeds and why:", ""]  # fmt: skip
    seeds = [r for r in records if r["kind"] == "seed"]
    for r in seeds:
        if r["failed"]:
            lines.append(f"- {r['task']} / {r['recipe']}, seed {r['seed']}: {'; '.join(r['why'])}")
    if not any(r["failed"] for r in seeds):
        lines.append("- none")
    for r in records:
        if r["kind"] == "error":
            lines.append(f"- {r['task']} / {r['recipe']}: the train command failed: "
                         f"{r['error'].splitlines()[0]}")  # fmt: skip
    commands = dict.fromkeys(r["command"] for r in records if "command" in r)  # (a merge's parts)
    lines += ["", "Train commands:", ""]
    lines += [f"- `{c}`" for c in commands]
    return lines


def plot(records: list[dict[str, Any]], title: str, path: Path) -> None:
    """One dot per seed: each recipe's worst axis (position, mm) of its first judgement,
    and the fraction of episodes outside 5 mm where episodes are judged by fraction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seeds = [r for r in records if r["kind"] == "seed"]
    groups = list(dict.fromkeys((r["task"], r["recipe"]) for r in seeds))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(groups) + 2), 4.5))
    for i, (task, recipe) in enumerate(groups):
        rows = [r for r in seeds if (r["task"], r["recipe"]) == (task, recipe)]
        ys = [_headline(r) for r in rows]
        xs = i + np.linspace(-0.25, 0.25, len(rows))
        colours = ["tab:red" if r["failed"] else "tab:blue" for r in rows]
        ax.scatter(xs, np.maximum(ys, 1e-3), c=colours, s=18, zorder=3)
    ax.scatter([], [], c="tab:blue", s=18, label="seed")
    ax.scatter([], [], c="tab:red", s=18, label="failed seed")
    ax.axhline(1.0, color="grey", lw=0.8, ls="--")
    ax.set_xticks(range(len(groups)))
    # a recipe with a long flag list (a teacher's path) wrapped, not cut off at the edge
    wrap = max(24, int(40 * max(6.0, 1.2 * len(groups) + 2) / 6.0 / max(1, len(groups))))
    labels = [t + "\n" + textwrap.fill(r, wrap, break_on_hyphens=False) for t, r in groups]
    ax.set_xticklabels(labels, fontsize=7)
    ax.set_yscale("log")
    from mara_mjx.viz.plots import finish_figure

    finish_figure(fig, ax, path, f"Robustness over seeds ({title})", "task / recipe",
                  "worst axis of the seed's mean error (mm)")  # fmt: skip


def _headline(row: dict[str, Any]) -> float:
    """A seed's worst mean axis error (mm): the paper's evaluation, else the poses."""
    if "paper" in row:
        return max(row["paper"]["position_mm"])
    return max(row["targets"]["position_mm"]["mean"])


def print_job(seeds: list[dict], summary: list[dict]) -> None:
    """One job's seeds on the console: the failed ones and why, each metric's mean and
    worst seed."""
    failed = [r for r in seeds if r["failed"]]
    print(f"{seeds[0]['task']} / {seeds[0]['recipe']}: {len(failed)} of {len(seeds)} seeds "
          "failed", flush=True)  # fmt: skip
    for r in failed:
        print(f"    seed {r['seed']}: {'; '.join(r['why'])}")
    for r in summary:
        print(f"  {r['metric']}: mean {_fmt(r['mean'])}, worst seed {r['worst_seed']} "
              f"{_fmt(r['worst'])}", flush=True)  # fmt: skip


TABLE: dict[str, Any] = {
    "title": "Robustness over seeds: each recipe's seeds, judged as their task is judged",
    "columns": [
        ("task", lambda r: r["task"]),
        ("recipe", lambda r: f"`{r['recipe']}`"),
        ("metric", lambda r: r["metric"] + (f" ({r['unit']})" if r["unit"] else "")),
        ("failed / seeds", lambda r: f"{len(r['failed_seeds'])} / {r['seeds']}"),
        ("mean", lambda r: _fmt(r["mean"])),
        ("median", lambda r: _fmt(r["median"])),
        ("IQM [95% CI]", _iqm_cell),
        ("worst seed", lambda r: f"{r['worst_seed']}: {_fmt(r['worst'])}"),
    ],
    "rows": _metric_rows,
    "notes": notes,
    "plot": plot,
}
