"""Figures: the paper's reward surface and training curves of runs.

    python -m mara_mjx.plots reward-shape --out reward_shape.png
    python -m mara_mjx.plots curves runs/MARA-a runs/MARA-b --out curves.png

`reward-shape`: the core reward r = D(d) O(theta) - 1 over distance d in [0, 1] m and
orientation angle theta in [0, pi] rad (a 3-D surface), with the paper's
hyperparameters alpha 5, beta 1.5, gamma 1, done 0.02 (delta 3 and eta 0.03 shape the
collision penalty C, which is not part of the surface), computed by `mara_mjx.envs.rewards`;
beside it D(d) - 1 against d on a log axis, where the sharp `done` term shows.

`curves`: mean reward per step and policy entropy against env steps, one line per run,
from each run folder's progress.csv (columns env_steps, reward_mean, entropy; written by
`mara_mjx.ppo.logger`). A CSV file may be given instead of a folder.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

PROG = "python -m mara_mjx.plots"
CURVE_COLUMNS = ("env_steps", "reward_mean", "entropy")


class PlotError(ValueError):
    """Missing or unreadable input, or an output that cannot be written."""


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def reward_surface(
    d: np.ndarray,
    theta: np.ndarray,
    alpha: float = 5.0,
    beta: float = 1.5,
    gamma: float = 1.0,
    done: float = 0.02,
) -> np.ndarray:
    """r = D(d) O(theta) - 1 on broadcast d (m) and theta (rad), via mara_mjx.envs.rewards."""
    from mara_mjx.envs import rewards

    distance = rewards.distance_term(np.asarray(d, np.float64), alpha, done)
    factor = rewards.orientation_factor(np.asarray(theta, np.float64), beta, gamma)
    return np.asarray(distance * factor - 1.0)


def plot_reward_shape(
    out: str | os.PathLike,
    alpha: float = 5.0,
    beta: float = 1.5,
    gamma: float = 1.0,
    delta: float = 3.0,
    eta: float = 0.03,
    done: float = 0.02,
) -> Path:
    """Write the reward-surface figure (PNG) to `out`."""
    from mara_mjx.envs import rewards

    plt = _pyplot()
    # Dense near 0: the precision bonus (scale `done`) lives in the first few centimetres.
    d = np.unique(np.r_[np.linspace(0.0, 0.05, 101), np.linspace(0.05, 1.0, 96)])
    theta = np.linspace(0.0, math.pi, 91)
    dd, tt = np.meshgrid(d, theta)
    r = reward_surface(dd, tt, alpha, beta, gamma, done)

    fig = plt.figure(figsize=(12, 5), dpi=100)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.plot_surface(dd, tt, r, cmap="viridis", linewidth=0, antialiased=True)
    ax.set_xlabel("distance d (m)")
    ax.set_ylabel("orientation angle theta (rad)")
    ax.set_zlabel("reward")
    ax.set_title(
        f"r = D(d) O(theta) - 1\nalpha={alpha:g}, beta={beta:g}, gamma={gamma:g}, done={done:g}"
    )
    ax.view_init(elev=25, azim=45)

    ax2 = fig.add_subplot(1, 2, 2)
    d_log = np.logspace(-4, 0, 400)
    core = np.asarray(rewards.distance_term(d_log, alpha, done)) - 1.0
    ax2.plot(d_log, core, label="D(d) - 1 (MARA)")
    penalty = np.asarray(rewards.collision_penalty(d_log, True, delta, eta))
    label = f"D(d) - 1 - C (collided; delta={delta:g}, eta={eta:g})"
    ax2.plot(d_log, core - penalty, "--", label=label)
    ax2.set_xscale("log")
    ax2.set_xlabel("distance d (m)")
    ax2.set_ylabel("reward")
    ax2.set_title("distance term")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend()
    fig.tight_layout()
    return _save(fig, out)


def read_curves(run: str | os.PathLike) -> dict[str, np.ndarray]:
    """The curve columns of a run folder's progress.csv (or of a CSV file given directly)."""
    from mara_mjx.ppo.logger import ProgressError, read_progress

    try:
        progress = read_progress(run, CURVE_COLUMNS)
    except ProgressError as e:
        raise PlotError(str(e)) from e
    return {c: progress[c] for c in CURVE_COLUMNS}


def plot_curves(runs: Sequence[str | os.PathLike], out: str | os.PathLike) -> Path:
    """Write mean reward and entropy against env steps of `runs` (PNG) to `out`."""
    if not runs:
        raise PlotError("give at least one run folder")
    curves = {str(run): read_curves(run) for run in runs}
    plt = _pyplot()
    fig, (ax_r, ax_e) = plt.subplots(1, 2, figsize=(12, 4.5), dpi=100)
    for run, c in curves.items():
        label = Path(run).name if Path(run).is_dir() else Path(run).parent.name or run
        ax_r.plot(c["env_steps"], c["reward_mean"], lw=1.2, label=label)
        ax_e.plot(c["env_steps"], c["entropy"], lw=1.2, label=label)
    ax_r.set_ylabel("mean reward per step")
    ax_e.set_ylabel("policy entropy (nats)")
    for ax in (ax_r, ax_e):
        ax.set_xlabel("env steps")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
    fig.tight_layout()
    return _save(fig, out)


def finish_figure(
    fig, ax, path: str | os.PathLike, title: str, xlabel: str, ylabel: str, legend_size: int = 8
) -> None:
    """The benchmark plots' common ending: labels, title, grid, legend, save (120 dpi), close."""
    import matplotlib.pyplot as plt

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=legend_size)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _save(fig, out: str | os.PathLike) -> Path:
    plt = _pyplot()
    out = Path(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, format="png")
    except OSError as e:
        raise PlotError(f"cannot write {str(out)!r}: {e}") from e
    finally:
        plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    from mara_mjx.cli.common import UserError

    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    shape = sub.add_parser("reward-shape", help="the paper's reward surface")
    shape.add_argument("--out", default="reward_shape.png", help="output PNG")
    for name, default in (("alpha", 5.0), ("beta", 1.5), ("gamma", 1.0)):
        shape.add_argument(f"--{name}", type=float, default=default)
    for name, default in (("delta", 3.0), ("eta", 0.03), ("done", 0.02)):
        shape.add_argument(f"--{name}", type=float, default=default)
    curves = sub.add_parser("curves", help="mean reward and entropy against env steps")
    curves.add_argument("runs", nargs="+", help="run folders (with progress.csv) or CSV files")
    curves.add_argument("--out", default="curves.png", help="output PNG")
    args = parser.parse_args(argv)
    try:
        if args.command == "reward-shape":
            out = plot_reward_shape(
                args.out, args.alpha, args.beta, args.gamma, args.delta, args.eta, args.done
            )
        else:
            out = plot_curves(args.runs, args.out)
    except PlotError as e:
        raise UserError(str(e)) from e
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    from mara_mjx.cli.common import run_cli

    sys.exit(run_cli(main, PROG))
