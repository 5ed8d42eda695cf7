"""The PPO studies of `python -m mara_mjx.benchmark`: `train` and `brax`.

train  Our PPO (a `mara_mjx.ppo.PRESETS` preset, default "default") end to end on each
       task: compile time, env steps/s including learning (steady state), and the error
       of the deterministic policy against wall-clock after every jitted call
       (`Trainer.run` of `--updates_per_call` updates), with the time to 5 mm and 1 mm.
       Two error measures per call: `det_error_mm` from the training metrics (mean over
       envs and axes of |e| after one deterministic step from the rollout-end states) and
       the "settled" error of the common scorer below. At the end, the paper's evaluation
       (`make_evaluate`: 10 noisy episodes stopped at 5 mm per axis) and the same run to
       the horizon (`EvalConfig(tolerance_mm=0)`).
brax   brax's PPO (`brax.training.agents.ppo.train.train`) on `make_brax_env(task)` against
       our PPO on the same task and the same number of env steps, hyperparameters taken
       from the same `PPOConfig` (see `brax_kwargs`). Both sides keep a (wall-clock,
       params) snapshot before training and after every jitted call (ours: each
       `Trainer.run`; brax: each training epoch, through `policy_params_fn`, with
       `num_evals` = calls + 1 so that the snapshot granularity is the same and
       `run_evals=False`, so brax spends no time evaluating). After training, outside the
       timed region, every snapshot of both sides is scored by the same scorer.

Common scorer and clocks: `mara_mjx.bench.ppo_runs` (the scorer is `make_scorer`; its
docstring defines `t_s`, `t_run_s` and the time to each threshold); brax's side, its
arguments from the same `PPOConfig` and its training run: `mara_mjx.bench.brax_peer`.
"""

from __future__ import annotations

import dataclasses
import importlib.util
from typing import Any, ClassVar

import jax
import numpy as np

import mara_mjx
from mara_mjx.bench.brax_peer import brax_kwargs, train_brax, unmatched
from mara_mjx.bench.ppo_runs import (
    THRESHOLDS_MM,
    ScoreConfig,
    make_scorer,
    score_snapshots,
    train_ours,
)
from mara_mjx.bench.runner import BenchConfig, Study
from mara_mjx.ppo import PRESETS, EvalConfig, EvalResult, TrainConfig, make_policy
from mara_mjx.ppo.evaluation import make_evaluate
from mara_mjx.viz.plots import finish_figure


def _act_ours(policy: Any, obs: jax.Array) -> jax.Array:
    return policy(obs)


# ------------------------------------------------------------------------ studies
@dataclasses.dataclass(frozen=True)
class TrainStudyConfig(BenchConfig):
    """The train study's settings: a PPO preset, some of its fields overridden."""

    preset: str = "default"
    """PPO preset (mara_mjx.ppo.PRESETS)."""
    total: int | None = None
    """Env steps per run (None: the preset's total_timesteps)."""
    num_envs: int | None = None
    """Override of the preset's num_envs."""
    num_steps: int | None = None
    """Override of the preset's num_steps."""
    num_minibatches: int | None = None
    """Override of the preset's num_minibatches."""
    update_epochs: int | None = None
    """Override of the preset's update_epochs."""
    seed: int | None = None
    """Override of the preset's seed."""
    updates_per_call: int = 16
    """PPO updates per jitted call = per curve point (brax: per epoch)."""
    episode_length: int = 1024
    """Horizon of training episodes."""
    score_episodes: int = 10
    """Scorer: episodes."""
    score_steps: int = 100
    """Scorer: steps per episode."""
    score_last: int = 10
    """Scorer: error averaged over the last steps."""
    eval_episodes: int = 10
    """Episodes of the final evaluations (train study)."""

    study: ClassVar[str] = "train"
    QUICK: ClassVar[dict[str, Any]] = {
        "total": 64,
        "num_envs": 4,
        "num_steps": 8,
        "num_minibatches": 2,
        "update_epochs": 2,
        "updates_per_call": 1,
        "episode_length": 16,
        "eval_episodes": 2,
        "score_episodes": 2,
        "score_steps": 8,
        "score_last": 4,
    }
    POSITIVE: ClassVar[tuple[str, ...]] = (
        "updates_per_call",
        "episode_length",
        "score_episodes",
        "score_steps",
        "score_last",
        "eval_episodes",
    )

    def __post_init__(self):
        super().__post_init__()
        if self.preset not in PRESETS:
            raise ValueError(f"preset={self.preset!r} is not valid; choose one of {list(PRESETS)}")
        if self.score_last > self.score_steps:
            raise ValueError("score_last must not exceed score_steps")
        config = ppo_config(self)  # PPOConfig's own validation, with its messages
        # brax is optional: without it the brax study's settings are checked when it runs
        # (and every other study's flags still build: the parser makes each default config)
        if self.study == "brax" and importlib.util.find_spec("brax") is not None:
            brax_kwargs(config.ppo, self.episode_length)


@dataclasses.dataclass(frozen=True)
class BraxStudyConfig(TrainStudyConfig):
    """The brax study's settings (eval_episodes unused)."""

    study: ClassVar[str] = "brax"


def ppo_config(args: TrainStudyConfig) -> TrainConfig:
    """The preset with the command line's overrides (validated by PPOConfig). For the
    brax study the total is rounded down to whole calls of `updates_per_call` updates
    (at least one), so that brax's epochs and our calls cover the same env steps."""
    fields = {
        "total_timesteps": args.total,
        "num_envs": args.num_envs,
        "num_steps": args.num_steps,
        "num_minibatches": args.num_minibatches,
        "update_epochs": args.update_epochs,
        "seed": args.seed,
    }
    config = PRESETS[args.preset].replace(**{k: v for k, v in fields.items() if v is not None})
    if args.study == "brax":
        per_call = args.updates_per_call * config.ppo.batch_size
        total = max(1, config.ppo.total_timesteps // per_call) * per_call
        if total != config.ppo.total_timesteps:
            config = config.replace(total_timesteps=total)
    return config


def score_config(args: TrainStudyConfig) -> ScoreConfig:
    return ScoreConfig(args.score_episodes, args.score_steps, args.score_last)


def _eval_summary(env: Any, policy: Any, config: EvalConfig) -> dict[str, Any]:
    out = jax.device_get(make_evaluate(env, config)(policy))
    s = EvalResult(**{k: np.asarray(v) for k, v in out.items()}).summary()
    return {
        "tolerance_mm": config.tolerance_mm,
        "episodes": s["episodes"],
        "mean_axis_error_mm": s["mean_axis_error_mm"],
        "position_error_mm": s["position_error_mm"]["mean"],
        "orientation_error_deg": s["orientation_error_deg"]["mean"],
        "reached_tolerance": s["reached_tolerance"],
        "steps": s["steps"]["mean"],
    }


def train_study(args: TrainStudyConfig) -> list[dict[str, Any]]:
    """Our PPO on every task: throughput, time to accuracy, final evaluations."""
    config = ppo_config(args)
    scoring = score_config(args)
    records = []
    for task in args.tasks:
        env = mara_mjx.make(task, max_episode_steps=args.episode_length)
        run, state = train_ours(env, task, config, args.updates_per_call)
        score_snapshots(run, make_scorer(env, _act_ours, scoring))
        policy = make_policy(state, config)
        evals = {
            "eval_stop_5mm": _eval_summary(env, policy, EvalConfig(episodes=args.eval_episodes)),
            "eval_horizon": _eval_summary(
                env, policy, EvalConfig(episodes=args.eval_episodes, tolerance_mm=0.0)
            ),
        }
        rec = {
            **run.summary(),
            **evals,
            "preset": args.preset,
            "num_envs": config.ppo.num_envs,
            "updates_per_call": args.updates_per_call,
            "episode_length": args.episode_length,
            "ppo": config.flat(),
            "score": dataclasses.asdict(scoring),
        }
        records.append(rec)
        print(
            f"{task:20s} {_mega(rec['env_steps_per_s'])} steps/s"
            f"  compile {rec['compile_s']:.1f} s"
            f"  det to 5 mm {_fmt(rec.get('det_error_to_5mm_s'), 1, 's')}"
            f"  settled to 5 mm {_fmt(rec.get('settled_to_5mm_s'), 1, 's')}"
            f"  eval {rec['eval_stop_5mm']['mean_axis_error_mm']:.2f} mm"
            f" / horizon {rec['eval_horizon']['mean_axis_error_mm']:.2f} mm",
            flush=True,
        )
    return records


def brax_study(args: BraxStudyConfig) -> list[dict[str, Any]]:
    """brax's PPO and ours on each task, same env steps, snapshots scored alike."""
    config = ppo_config(args)
    scoring = score_config(args)
    kwargs = brax_kwargs(config.ppo, args.episode_length)
    kwargs_json = {k: v for k, v in kwargs.items() if k != "network_factory"}
    kwargs_json["network"] = (
        f"make_ppo_networks(policy and value {list(config.ppo.hidden_sizes)}, tanh)"
    )
    records = []
    for task in args.tasks:
        env = mara_mjx.make(task, max_episode_steps=args.episode_length)
        ours, _ = train_ours(env, task, config, args.updates_per_call)
        score_snapshots(ours, make_scorer(env, _act_ours, scoring))
        theirs, act = train_brax(task, config.ppo, args.updates_per_call, args.episode_length)
        score_snapshots(theirs, make_scorer(env, act, scoring))
        a, b = ours.summary(), theirs.summary()
        common = {"score": dataclasses.asdict(scoring), "num_envs": config.ppo.num_envs}
        b = {**b, **common, "brax_kwargs": kwargs_json, "unmatched": unmatched(config)}
        a = {**a, **common, "preset": args.preset, "ppo": config.flat()}
        a["brax_over_ours_time_to_5mm"] = _ratio(b.get("settled_to_5mm_s"), a["settled_to_5mm_s"])
        a["ours_over_brax_env_steps_per_s"] = _ratio(a["env_steps_per_s"], b["env_steps_per_s"])
        records += [a, b]
        print(
            f"{task:20s} ours {_mega(a['env_steps_per_s'])} steps/s, 5 mm at "
            f"{_fmt(a.get('settled_to_5mm_s'), 1, 's')}; brax "
            f"{_mega(b['env_steps_per_s'])} steps/s, 5 mm at "
            f"{_fmt(b.get('settled_to_5mm_s'), 1, 's')}",
            flush=True,
        )
    return records


# ------------------------------------------------------------------ output specs
def _ratio(a: float | None, b: float | None) -> float | None:
    return a / b if a is not None and b else None


def _fmt(x: float | None, unit: float, suffix: str) -> str:
    """x / unit to 3 significant digits with a suffix, or 'not reached' for None."""
    return "not reached" if x is None else f"{x / unit:.3g} {suffix}"


def _mega(x: float | None) -> str:
    """Millions to 3 significant digits, or '' for None."""
    return "" if x is None else f"{x / 1e6:.3g} M"


def _cell(x: float | None, digits: int = 1) -> str:
    return "" if x is None else f"{x:.{digits}f}"


def _plot_error_curves(
    records: list[dict[str, Any]], curves: list[tuple[str, str, str]], title: str, path: Any
) -> None:
    """Error (log y) vs wall-clock without compile. `curves`: (curve key, line style,
    label suffix) drawn for every record, one colour per (task, impl) pair."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    for i, r in enumerate(records):
        colour = f"C{i % 10}"
        for key, style, suffix in curves:
            pts = [(p["t_run_s"], p[key]) for p in r["curve"] if p.get(key) is not None]
            if pts:
                label = f"{r['task']} {suffix.format(impl=r['impl'])}"
                ax.plot(*zip(*pts, strict=True), style, color=colour, marker=".", label=label)
    for mm in THRESHOLDS_MM:
        ax.axhline(mm, color="grey", linewidth=0.8, linestyle=":")
    ax.set_yscale("log")
    xlabel = "wall-clock since start of training, compile excluded (s)"
    finish_figure(fig, ax, path, title, xlabel, "mean per-axis error (mm)", legend_size=7)


def plot_train(records: list[dict[str, Any]], title: str, path: Any) -> None:
    _plot_error_curves(
        records,
        [("det_error_mm", "-", "(det_error_mm)"), ("settled_mm", "--", "(settled)")],
        title,
        path,
    )


def plot_brax(records: list[dict[str, Any]], title: str, path: Any) -> None:
    _plot_error_curves(records, [("settled_mm", "-", "{impl}")], title, path)


def _score_note(records: list[dict[str, Any]]) -> str:
    s = records[0]["score"] if records else dataclasses.asdict(ScoreConfig())
    return (
        f"Settled error: the deterministic policy for {s['steps']} steps from "
        f"{s['episodes']} resets with {s['noise']} rad noise, mean per-axis |e| over the "
        f"last {s['last']} steps and the episodes. Times are wall-clock since the start of "
        "training with JAX's compile time subtracted (JSON: `t_s` with compile, `t_run_s` "
        "without); one point per jitted call."
    )


def _final_errors(r: dict[str, Any]) -> str:
    return f"{_cell(r.get('final_det_error_mm'), 2)} / {_cell(r.get('final_settled_mm'), 2)}"


def _eval_errors(r: dict[str, Any]) -> str:
    stop, horizon = r["eval_stop_5mm"], r["eval_horizon"]
    return f"{stop['mean_axis_error_mm']:.2f} / {horizon['mean_axis_error_mm']:.2f}"


TRAIN_TABLE: dict[str, Any] = {
    "title": "train study: our PPO end to end, time to accuracy",
    "columns": [
        ("task", lambda r: r["task"]),
        ("envs", lambda r: f"{r['num_envs']:,}"),
        ("env steps", lambda r: f"{r['env_steps']:,}"),
        ("compile (s)", lambda r: _cell(r["compile_s"])),
        ("env steps/s", lambda r: _mega(r["env_steps_per_s"])),
        ("det to 5 mm (s)", lambda r: _cell(r.get("det_error_to_5mm_s"))),
        ("det to 1 mm (s)", lambda r: _cell(r.get("det_error_to_1mm_s"))),
        ("settled to 5 mm (s)", lambda r: _cell(r.get("settled_to_5mm_s"))),
        ("settled to 1 mm (s)", lambda r: _cell(r.get("settled_to_1mm_s"))),
        ("final det / settled (mm)", _final_errors),
        ("eval stop 5 mm / horizon (mm)", _eval_errors),
    ],
    "notes": lambda records: [
        "`det`: `det_error_mm` of the training metrics (one deterministic step from the "
        "rollout-end states). " + _score_note(records) + " Eval: the paper's evaluation "
        "(`make_evaluate`: noisy episodes stopped at 5 mm per axis) and the same run to "
        "the horizon, mean per-axis error of the final policy."
    ],
    "plot": plot_train,
}


def _brax_note(records: list[dict[str, Any]]) -> str:
    theirs = next((r for r in records if "unmatched" in r), {})
    ours_only = ", ".join(f"{k} {v}" for k, v in theirs.get("unmatched", {}).items())
    return (
        _score_note(records) + " brax ran with `run_evals=False` (no evaluation cost); its "
        "hyperparameters (`brax_kwargs` in the JSON) come from the same PPOConfig, entropy "
        "cost 0 on both sides. Ours only, brax has no equivalent: "
        f"{ours_only or 'nothing'}; brax's constant learning rate, Adam eps 1e-8, "
        "tanh-squashed absolute actions and its own initialisation and noise "
        "parametrisation (`mara_mjx.bench.ppo.brax_kwargs`)."
    )


BRAX_TABLE: dict[str, Any] = {
    "title": "brax study: brax's PPO vs ours, same task, same env steps",
    "columns": [
        ("task", lambda r: r["task"]),
        ("implementation", lambda r: r["impl"]),
        ("env steps", lambda r: f"{r['env_steps']:,}"),
        ("env steps/s", lambda r: _mega(r["env_steps_per_s"])),
        ("compile (s)", lambda r: _cell(r["compile_s"])),
        ("to 5 mm (s)", lambda r: _cell(r.get("settled_to_5mm_s"))),
        ("to 1 mm (s)", lambda r: _cell(r.get("settled_to_1mm_s"))),
        ("final settled (mm)", lambda r: _cell(r.get("final_settled_mm"), 2)),
        ("brax / ours time to 5 mm", lambda r: _cell(r.get("brax_over_ours_time_to_5mm"), 2)),
        ("ours / brax steps/s", lambda r: _cell(r.get("ours_over_brax_env_steps_per_s"), 2)),
    ],
    "notes": lambda records: [_brax_note(records)],
    "plot": plot_brax,
}


TRAIN = Study("train", TrainStudyConfig, train_study, TRAIN_TABLE, "our PPO end to end")
BRAX = Study("brax", BraxStudyConfig, brax_study, BRAX_TABLE, "brax's PPO against ours")
