"""Accuracy of a random-target policy over held-out target poses.

`python -m mara_mjx.evaluate RUN` runs this instead of the paper's 10-episode table when
the checkpoint's task is a random-target one (MARARandomTarget, MARAOrientRandomTarget,
MARACollisionRandomTarget, MARACollisionOrientRandomTarget):

* Poses: `--episodes` (1,000 by default) distinct poses of the run's region (its env
  config, with any env flags on top), from `envs.targets.evaluation_poses`: numpy
  SeedSequence(`--seed`, spawn_key=(1,)), while every training table uses spawn_key (0,).
  The two streams are independent whatever the seeds, so no held-out pose is a training
  pose; the report gives each pose's distance to the nearest pose of the run's training
  table as evidence.
* Episodes: one per pose, all in one vmap (`ppo.evaluation.make_evaluate` with one
  params row per episode whose table holds just that pose), each from the reset pose
  perturbed by `--noise` (0.02 rad), keys split(key(seed), episodes), the deterministic
  policy (the Gaussian mean).
* Stop rule: none by default (`tolerance_mm` 0): every episode runs to the horizon and
  its error is that of the last step, i.e. where the policy holds the arm, not the first
  step it passes within 5 mm. `--tolerance_mm 5` gives the paper's stop rule instead.
* Report: per axis (x, y, z in mm; for the Orient tasks also roll, pitch, yaw of quat_err
  in degrees) the mean, median, 95th percentile and worst error over the poses; the
  fraction of poses with every axis within 5 mm and within 1 mm (and 5 and 1 degrees);
  collisions (total, and episodes with any). Written as JSON (with every episode), a
  markdown table and a figure of the error over the workspace (worst-axis error vs the
  target's x, y and z, and a top view), next to each other:
  <run>/eval-<checkpoint>-<driver>-targets.{json,md,png} unless `--json` says where.

The env flags of `evaluate` (e.g. `--driver real --velocity 0.3`, `--max_episode_steps`,
`--target_min`, `--target_spread_deg`) apply as for the paper's table.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from mara_mjx.envs import targets
from mara_mjx.envs.random_target import with_targets
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import EvalResult, evaluate

DEFAULTS = EvalConfig(episodes=1000, tolerance_mm=0.0)
"""Evaluation defaults of the random-target tasks (flags given by the user win)."""
THRESHOLDS_MM = (5.0, 1.0)
THRESHOLDS_DEG = (5.0, 1.0)
POSITION_AXES = ("x", "y", "z")
ORIENTATION_AXES = ("roll", "pitch", "yaw")


@dataclasses.dataclass(frozen=True)
class TargetEvalResult:
    """Per-pose numbers, (E, ...) numpy arrays."""

    result: EvalResult  # errors at each episode's last step (see ppo.evaluation)
    target_pos: np.ndarray  # (E, 3) m, world frame
    target_quat: np.ndarray  # (E, 4) (w, x, y, z)
    nearest_training_mm: np.ndarray  # (E,) distance to the nearest training-table position

    def summary(self, orientation: bool) -> dict[str, Any]:
        r = self.result
        pos = np.asarray(r.position_error_mm, np.float64)
        out: dict[str, Any] = {
            "poses": len(pos),
            "position_error_mm": axis_stats(pos),
            "position_error_norm_mm": axis_stats(np.linalg.norm(pos, axis=1)),
            "within_mm": {f"{t:g}": _fraction(pos <= t) for t in THRESHOLDS_MM},
            "collisions": int(np.sum(r.collisions)),
            "episodes_with_collisions": int(np.sum(r.collisions > 0)),
            "steps": axis_stats(np.asarray(r.steps, np.float64)),
            "reached_tolerance": int(np.sum(r.reached)),
            "nearest_training_pose_mm": {
                "min": float(np.min(self.nearest_training_mm)),
                "median": float(np.median(self.nearest_training_mm)),
            },
        }
        if orientation:
            ori = np.asarray(r.orientation_error_deg, np.float64)
            out["orientation_error_deg"] = axis_stats(ori)
            out["within_deg"] = {f"{t:g}": _fraction(ori <= t) for t in THRESHOLDS_DEG}
            out["within_mm_and_deg"] = {
                f"{a:g} mm, {b:g} deg": _fraction(np.concatenate([pos <= a, ori <= b], 1))
                for a, b in zip(THRESHOLDS_MM, THRESHOLDS_DEG, strict=True)
            }
        return out

    def episodes(self) -> list[dict[str, Any]]:
        rows = self.result.episodes()
        for row, pos, quat, near in zip(
            rows, self.target_pos, self.target_quat, self.nearest_training_mm, strict=True
        ):
            row["target_pos"] = pos.tolist()
            row["target_quat"] = quat.tolist()
            row["nearest_training_pose_mm"] = float(near)
        return rows


def axis_stats(x: np.ndarray) -> dict[str, Any]:
    """Mean, median, 95th percentile (numpy's linear interpolation) and worst over the
    first axis: lists for (E, k) input, numbers for (E,)."""
    x = np.asarray(x, np.float64)
    stats = {
        "mean": np.mean(x, 0),
        "median": np.median(x, 0),
        "p95": np.percentile(x, 95, axis=0),
        "max": np.max(x, 0),
    }
    return {k: v.tolist() if np.ndim(v) else float(v) for k, v in stats.items()}


def _fraction(ok: np.ndarray) -> float:
    """Fraction of rows with every entry true."""
    return float(np.mean(np.all(ok, axis=1)))


def eval_config(overrides: dict[str, Any]) -> EvalConfig:
    """DEFAULTS with the eval flags the user gave."""
    return DEFAULTS.replace(**overrides)


def evaluate_targets(env: Any, policy: Any, config: EvalConfig) -> TargetEvalResult:
    """Run `config.episodes` episodes of the deterministic policy, one per held-out pose
    of the env's region (compiles once per env and config). ValueError if the region
    holds fewer distinct poses."""
    poses = targets.evaluation_poses(env.arm.mj_model, env.region, config.episodes, config.seed)
    params = with_targets(env.make_params(reset_noise=config.noise), poses.pos, poses.quat)
    result = evaluate(env, policy, config, params)
    train = env.pose_table().pos
    gaps = np.linalg.norm(poses.pos[:, None, :] - train[None, :, :], axis=-1)
    return TargetEvalResult(result, poses.pos, poses.quat, 1000.0 * gaps.min(axis=1))


# ---------------------------------------------------------------------- reporting
def format_markdown(
    task: str, env: Any, summary: dict[str, Any], orientation: bool, config: EvalConfig
) -> str:
    """The per-axis table and one summary row (for a table across tasks)."""
    cfg = env.config
    driver = cfg.driver + (f", {cfg.velocity:g} rad/s" if cfg.driver == "real" else "")
    stop = (
        f"stopped when every axis of |e| <= {config.tolerance_mm:g} mm, else at the horizon"
        if config.tolerance_mm > 0
        else f"error at the last of {env.max_episode_steps} steps"
    )
    near = summary["nearest_training_pose_mm"]
    lines = [
        f"### {task}, {driver} driver: {summary['poses']} held-out poses",
        "",
        f"Region: TCP in [{_vec(cfg.target_min)}, {_vec(cfg.target_max)}] m"
        + (
            f", orientation within {cfg.target_spread_deg:g} deg of {_vec(cfg.target_quat)}"
            if orientation
            else ""
        )
        + f"; evaluation seed {config.seed} (stream {targets.EVAL_STREAM}; training table "
        f"seed {cfg.target_seed}, stream {targets.TRAIN_STREAM}, {cfg.target_table_size} "
        f"poses; nearest training pose {near['median']:.1f} mm away at the median, "
        f"{near['min']:.2f} mm at least). Deterministic policy, reset noise "
        f"{config.noise:g} rad, {stop}.",
        "",
    ]
    header = ["statistic", *(f"{a} (mm)" for a in POSITION_AXES)]
    if orientation:
        header += [f"{a} (deg)" for a in ORIENTATION_AXES]
    lines += ["| " + " | ".join(header) + " |", "|---" + "|---:" * (len(header) - 1) + "|"]
    for key, label in (("mean", "mean"), ("median", "median"), ("p95", "95th percentile"),
                       ("max", "worst")):  # fmt: skip
        cells = summary["position_error_mm"][key]
        if orientation:
            cells = cells + summary["orientation_error_deg"][key]
        lines.append(f"| {label} | " + " | ".join(f"{v:.2f}" for v in cells) + " |")
    within = ", ".join(f"{100 * v:.1f}% within {k} mm" for k, v in summary["within_mm"].items())
    if orientation:
        within += "; " + ", ".join(
            f"{100 * v:.1f}% within {k} deg" for k, v in summary["within_deg"].items()
        )
    lines += [
        "",
        f"Every axis: {within}. Collisions: {summary['collisions']} "
        f"(in {summary['episodes_with_collisions']} of {summary['poses']} episodes).",
        "",
        "Summary row:",
        "",
        "| task | driver | poses | mean x, y, z (mm) | p95 x, y, z (mm) | worst (mm) "
        "| within 5 / 1 mm | mean roll, pitch, yaw (deg) | p95 (deg) | collisions |",
        "|---|---|---:|---|---|---:|---|---|---|---:|",
        "| "
        + " | ".join(
            [
                task,
                driver,
                str(summary["poses"]),
                _vec(summary["position_error_mm"]["mean"], 2),
                _vec(summary["position_error_mm"]["p95"], 2),
                f"{max(summary['position_error_mm']['max']):.2f}",
                " / ".join(f"{100 * v:.1f}%" for v in summary["within_mm"].values()),
                _vec(summary["orientation_error_deg"]["mean"], 2) if orientation else "",
                _vec(summary["orientation_error_deg"]["p95"], 2) if orientation else "",
                str(summary["collisions"]),
            ]
        )
        + " |",
    ]
    return "\n".join(lines)


def _vec(values, digits: int = 3) -> str:
    return "(" + ", ".join(f"{v:.{digits}f}" for v in values) + ")"


def plot(path: Path, res: TargetEvalResult, orientation: bool, title: str) -> Path:
    """PNG: the worst-axis error of each pose against its target x, y and z, and a top
    view coloured by it; for the Orient tasks a second row for the orientation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [("position: worst axis |e| (mm)", res.result.position_error_mm.max(1), THRESHOLDS_MM)]
    if orientation:
        ori = res.result.orientation_error_deg.max(1)
        rows.append(("orientation: worst axis (deg)", ori, THRESHOLDS_DEG))
    fig, axes = plt.subplots(len(rows), 4, figsize=(16, 3.6 * len(rows)), squeeze=False)
    floor = 1e-3
    for (label, err, thresholds), ax_row in zip(rows, axes, strict=True):
        shown = np.maximum(err, floor)
        for k, ax in enumerate(ax_row[:3]):
            ax.scatter(res.target_pos[:, k], shown, s=6, alpha=0.6)
            for t, style in zip(thresholds, ("--", ":"), strict=True):
                ax.axhline(t, color="k", linestyle=style, linewidth=0.8, label=f"{t:g}")
            ax.set_yscale("log")
            ax.set_xlabel(f"target {POSITION_AXES[k]} (m)")
            ax.set_ylabel(label)
            ax.grid(True, which="both", alpha=0.3)
        top = ax_row[3]
        order = np.argsort(shown)  # the worst on top
        sc = top.scatter(
            res.target_pos[order, 0],
            res.target_pos[order, 1],
            c=np.log10(shown[order]),
            s=8,
            cmap="viridis",
        )
        top.set_xlabel("target x (m)")
        top.set_ylabel("target y (m)")
        top.set_aspect("equal")
        fig.colorbar(sc, ax=top, label="log10 " + label)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run(
    *,
    name: str,
    source: dict[str, Any],
    heading: str,
    env: Any,
    policy: Any,
    eval_overrides: dict[str, Any],
    json_path: str,
) -> int:
    """The random-target branch of `python -m mara_mjx.evaluate` (flags already parsed):
    `name` the env's, `source` the report's fields on the policy evaluated (a checkpoint's
    or an exported file's), `heading` its first printed line."""
    from mara_mjx.cli.common import UserError
    from mara_mjx.runtime import files
    from mara_mjx.runtime import runs as ckpt

    try:
        config = eval_config(eval_overrides)
    except ValueError as e:
        raise UserError(f"invalid eval config: {e}") from e
    out = Path(json_path)
    try:
        files.check_writable(out.parent)
    except OSError as e:
        raise UserError(f"cannot write the report to {str(out)!r}: {e}") from e
    orientation = bool(env.task.orientation)
    print(heading)
    print(
        f"env: {name}, driver {env.config.driver!r}"
        + (f", velocity {env.config.velocity:g} rad/s" if env.config.driver == "real" else "")
        + f", horizon {env.max_episode_steps} steps; {config.episodes} held-out target poses",
        flush=True,
    )
    try:
        res = evaluate_targets(env, policy, config)
    except ValueError as e:
        raise UserError(str(e)) from e
    summary = res.summary(orientation)
    table = format_markdown(name, env, summary, orientation, config)
    print(table)
    report = {
        **{k: v for k, v in source.items() if k in ("checkpoint", "exported_policy")},
        "env_name": name,
        "env_config": env.config.to_dict(),
        "eval": config.to_dict(),
        "held_out": {
            "stream": targets.EVAL_STREAM,
            "training_stream": targets.TRAIN_STREAM,
            "how": "envs.targets.evaluation_poses: numpy SeedSequence(eval seed, "
            "spawn_key=(1,)); training tables use spawn_key (0,)",
        },
        **{k: v for k, v in source.items() if k not in ("checkpoint", "exported_policy")},
        **ckpt.provenance(),
        "summary": summary,
        "episodes": res.episodes(),
    }
    ckpt.write_json(out, report)
    md = out.with_suffix(".md")
    md.write_text(table + "\n")
    png = plot(out.with_suffix(".png"), res, orientation, f"{name}, {env.config.driver} driver")
    print(f"wrote {out}, {md.name} and {png.name}")
    return 0
