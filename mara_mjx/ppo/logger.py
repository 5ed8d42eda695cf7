"""Host-side logging of a training run: CSV, TensorBoard, time-to-accuracy, plots.

One CSV row per PPO update (`progress.csv` in the run folder), with units in the column
names. `time_s` is wall-clock seconds since the command started (compile included; on a
resumed run, the time of the run up to the checkpoint plus that of the new command); all
updates of one jitted call share the call's time.

A resumed run rewrites its progress.csv without the rows logged after its checkpoint:
atomically (`mara_mjx.runtime.files.write_atomic`), so an interrupt or a crash mid-rewrite leaves
the old file whole. A progress.csv without an `update` column cannot be continued
(`check_progress` says so before anything is rewritten).
"""

from __future__ import annotations

import csv
import io
import math
import os
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

AXES = ("x", "y", "z")
BASE_COLUMNS = (
    "update",
    "env_steps",
    "time_s",
    "steps_per_s",
    "reward_mean",
    "episode_return",
    "episodes",
    "distance_mm",
    *(f"pos_err_{a}_mm" for a in AXES),
    "det_error_mm",
    *(f"det_err_{a}_mm" for a in AXES),
    "det_distance_mm",
    "reach_error_mm",
)
ORIENT_COLUMNS = (
    *(f"ori_err_{a}_deg" for a in AXES),
    *(f"det_ori_err_{a}_deg" for a in AXES),
)
TAIL_COLUMNS = (
    "collision_rate",
    "nonfinite_actions",
    "terminations",
    "entropy",
    "policy_loss",
    "value_loss",
    "loss",
    "approx_kl",
    "clip_frac",
    "grad_norm",
    "explained_variance",
    "learning_rate",
)
# Metric name -> CSV columns, for the (3,) per-axis metrics.
_VECTOR_COLUMNS = {
    "position_error_mm": "pos_err_{}_mm",
    "det_position_error_mm": "det_err_{}_mm",
    "orientation_error_deg": "ori_err_{}_deg",
    "det_orientation_error_deg": "det_ori_err_{}_deg",
}
ACCURACY_THRESHOLDS_MM = (5.0, 1.0)


def columns(orientation: bool) -> tuple[str, ...]:
    return BASE_COLUMNS + (ORIENT_COLUMNS if orientation else ()) + TAIL_COLUMNS


def rows_from_metrics(
    metrics: dict[str, np.ndarray],
    first_update: int,
    steps_per_update: int,
    time_s: float,
    steps_per_s: float,
) -> list[dict[str, float]]:
    """CSV rows of the valid updates of one `Trainer.run` call (host numpy metrics)."""
    rows = []
    valid = np.asarray(metrics["valid"])
    for i in np.flatnonzero(valid):
        update = first_update + len(rows) + 1
        row: dict[str, float] = {
            "update": update,
            "env_steps": update * steps_per_update,  # Python int: no overflow
            "time_s": time_s,
            "steps_per_s": steps_per_s,
        }
        for name, value in metrics.items():
            if name == "valid":
                continue
            value = np.asarray(value[i])
            if name in _VECTOR_COLUMNS:
                for axis, v in zip(AXES, value, strict=True):
                    row[_VECTOR_COLUMNS[name].format(axis)] = float(v)
            else:
                row[name] = float(value)
        rows.append(row)
    return rows


class Milestones:
    """Wall-clock time and env steps when the deterministic mean per-axis error first
    drops below each threshold: `reach_error_mm` (the probe from the reset of
    CurriculumConfig.probe_reach_steps) where the rows have it, else `det_error_mm`."""

    def __init__(self, records: dict[str, Any] | None = None):
        self.records: dict[str, Any] = dict(records or {})

    def update(self, rows: Iterable[dict[str, float]]) -> list[str]:
        """Record new crossings; returns messages for them."""
        messages = []
        for row in rows:
            # CurriculumConfig.probe_reach_steps' probe from the reset where the run has one
            err = row["reach_error_mm"] if "reach_error_mm" in row else row.get("det_error_mm")
            err = math.nan if err is None else err
            for mm in ACCURACY_THRESHOLDS_MM:
                key = f"{mm:g}mm"
                if key not in self.records and err < mm:
                    self.records[key] = {
                        "time_s": row["time_s"],
                        "env_steps": int(row["env_steps"]),
                        "update": int(row["update"]),
                    }
                    messages.append(
                        f"mean per-axis error {err:.3f} mm < {mm:g} mm after "
                        f"{row['time_s']:.1f} s, {int(row['env_steps'])} env steps"
                    )
        return messages


class RunLogger:
    """Appends rows to <run>/progress.csv and TensorBoard scalars to <run>/tb.

    `resume_update`: on a resumed run, rows after this update (logged after the
    checkpoint by the interrupted command) and rows cut short by a crash are dropped
    first, in one atomic rewrite, so the CSV has each update once. ProgressError if the
    existing CSV cannot be continued (`check_progress`)."""

    def __init__(
        self,
        run_dir: Path,
        columns: tuple[str, ...],
        tensorboard: bool,
        resume_update: int | None = None,
        resume_env_steps: int = 0,
    ):
        self.path = run_dir / "progress.csv"
        self.columns = columns
        if resume_update is not None and self.path.exists():
            check_progress(self.path)
            kept = [r for r in read_csv(self.path) if _update(r) <= resume_update]
            self._rewrite(kept)
        elif not self.path.exists() or resume_update is None:
            self._rewrite([])
        self.writer = None
        if tensorboard:
            from tensorboardX import SummaryWriter

            purge = resume_env_steps + 1 if resume_update is not None else None
            self.writer = SummaryWriter(str(run_dir / "tb"), purge_step=purge)

    def _write(self, f: Any, rows: list[dict[str, Any]], header: bool) -> None:
        writer = csv.DictWriter(f, fieldnames=self.columns, extrasaction="ignore")
        if header:
            writer.writeheader()
        writer.writerows({c: r.get(c, math.nan) for c in self.columns} for r in rows)

    def _rewrite(self, rows: list[dict[str, Any]]) -> None:
        """The header and `rows`, replacing the file atomically."""
        from mara_mjx.runtime import files

        text = io.StringIO(newline="")
        self._write(text, rows, header=True)
        files.write_atomic(self.path, text.getvalue())

    def log(self, rows: list[dict[str, float]]) -> None:
        with open(self.path, "a", newline="") as f:
            self._write(f, rows, header=False)
        if self.writer is not None:
            for row in rows:
                step = int(row["env_steps"])
                for name in self.columns[2:]:
                    value = row.get(name, math.nan)
                    if math.isfinite(value):
                        self.writer.add_scalar(name, value, step)
            self.writer.flush()

    def close(self) -> None:
        writer, self.writer = self.writer, None
        if writer is None:
            return
        try:
            writer.close()
        except RuntimeError as e:  # "can't start new thread": memory exhausted (NOTES 31)
            # tensorboardX's writer thread stops on a signal sent through a queue whose
            # feeder thread could not start; its atexit cleanup would then wait for it
            # forever at exit: mark its files closed (the unflushed events are lost)
            for file_writer in (getattr(writer, "all_writers", None) or {}).values():
                file_writer.event_writer._closed = True
            print(f"mara_mjx: TensorBoard events not flushed: {e}", file=sys.stderr)


def read_csv(path: str | os.PathLike) -> list[dict[str, str]]:
    """The rows of a progress.csv as written (strings), for rewriting it."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


class ProgressError(ValueError):
    """A missing, unreadable or incomplete progress.csv."""


def _update(row: dict[str, Any]) -> float:
    """A row's update number; infinity for a row cut short or not a number (dropped on
    resume)."""
    if None in row.values() or None in row:
        return math.inf
    try:
        return float(row["update"])
    except (TypeError, ValueError):
        return math.inf


def check_progress(path: str | os.PathLike) -> None:
    """ProgressError unless the progress.csv `path` can be continued: readable, with an
    `update` column."""
    try:
        with open(path, newline="") as f:
            fields = csv.DictReader(f).fieldnames or []
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise ProgressError(f"cannot read {str(path)!r}: {e}") from e
    if "update" not in fields:
        raise ProgressError(f"{str(path)!r} has no 'update' column")


def read_progress(
    run: str | os.PathLike, required: Iterable[str] = ("update", "env_steps")
) -> dict[str, np.ndarray]:
    """Every column of a run folder's progress.csv (or of a CSV file given directly) as a
    float array, NaN where empty: the one reader of the logs, for plots and summaries.
    ProgressError names the file and what is wrong (missing, a `required` column
    absent, no rows yet, a non-numeric value)."""
    path = Path(run)
    if not path.exists():
        raise ProgressError(f"run folder {str(path)!r} does not exist")
    csv_path = path / "progress.csv" if path.is_dir() else path
    if not csv_path.is_file():
        raise ProgressError(f"run folder {str(path)!r} has no progress.csv")
    try:
        with open(csv_path, newline="") as f:
            reader = csv.DictReader(f)
            rows = list(reader)
            fields = reader.fieldnames or []
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise ProgressError(f"cannot read {str(csv_path)!r}: {e}") from e
    missing = [c for c in required if c not in fields]
    if missing:
        raise ProgressError(f"{str(csv_path)!r} lacks the column(s) {missing}")
    if not rows:
        raise ProgressError(f"{str(csv_path)!r} has no rows yet")
    out = {}
    for c in fields:
        try:
            out[c] = np.array([float(r[c]) if r[c] not in ("", None) else np.nan for r in rows])
        except (TypeError, ValueError) as e:
            raise ProgressError(f"{str(csv_path)!r}: column {c!r} is not numeric: {e}") from e
    return out


MAX_RESTART_MARKS = 40
"""save_plots marks synchronised episode restarts with lines up to this many."""


def save_plots(
    csv_path: str | os.PathLike,
    out_dir: str | os.PathLike,
    title: str = "",
    reset_every: int = 0,
) -> list[Path]:
    """PNG plots against env steps, as the paper's figures: mean reward, policy entropy,
    and the accuracy metric (reach_error_mm where the run probed it, else det_error_mm;
    log scale); each with `title` (the run) and written atomically. `reset_every` > 0:
    every env's episode restarts together every that many env steps (synchronised
    episodes: num_envs x max_episode_steps), marked with dashed lines, since the
    training curves jump there."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mara_mjx.runtime import files

    progress = read_progress(csv_path)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    steps = progress["env_steps"]
    probed = np.any(np.isfinite(progress.get("reach_error_mm", np.array([math.nan]))))
    error = (
        ("reach_error_mm", "mean per-axis error of the saved policy, probed from the reset (mm)")
        if probed
        else ("det_error_mm", "mean per-axis error, one deterministic step per env (mm)")
    )
    plots = [
        ("reward.png", "reward_mean", "mean reward per env step (sampled policy)", False),
        ("entropy.png", "entropy", "policy entropy (nats)", False),
        ("error.png", *error, True),
    ]
    written = []
    for filename, column, label, log in plots:
        values = progress.get(column, np.full(len(steps), math.nan))
        ok = np.isfinite(values)
        fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=100)
        ax.plot(steps[ok], values[ok], lw=1.2, marker="." if ok.sum() < 50 else None)
        restarts = np.zeros(0)
        if reset_every > 0 and len(steps):
            restarts = np.arange(reset_every, steps[-1] + 1, reset_every)
        if 0 < len(restarts) <= MAX_RESTART_MARKS:
            for x in restarts:
                ax.axvline(x, color="grey", lw=0.6, ls="--", alpha=0.6)
            ax.plot([], [], color="grey", lw=0.6, ls="--",
                    label="all episodes restart together")  # fmt: skip
            ax.legend(fontsize=7, loc="best")
        elif len(restarts):  # e.g. one env (the paper's preset): a line per episode
            ax.plot([], [], " ", label=f"all episodes restart together every {reset_every:,} "
                    "env steps (not marked: too many)")  # fmt: skip
            ax.legend(fontsize=7, loc="best")
        ax.set_xlabel("env steps")
        ax.set_ylabel(label, fontsize=8)
        ax.set_title(title or Path(csv_path).parent.name, fontsize=9)
        if log and np.any(values[ok] > 0):
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        path = out_dir / filename
        files.write_atomic(path, lambda f, fig=fig: fig.savefig(f, format="png"))
        plt.close(fig)
        written.append(path)
    return written
