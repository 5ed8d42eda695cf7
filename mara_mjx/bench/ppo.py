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

The common scorer (`make_scorer`, `ScoreConfig`): the deterministic policy for
`steps` (100) steps from `episodes` (10) resets perturbed by `noise` (0.02 rad, the
paper evaluation's reset noise), no early stop; the error is the mean per-axis |e| in mm
averaged over the last `last` (10) steps and over the episodes ("settled" error), so
that a policy that reaches the target and leaves it again is not counted as accurate.
Ours acts through `make_policy` (the Gaussian mean, joint targets in rad); brax's
deterministic action (tanh of the Gaussian mean, in [-1, 1]) goes through the adapter's
affine map onto the joint box (`BraxMaraEnv.to_joint_targets`).

Clocks. `t_s`: wall-clock seconds since the start of training (ours: before
`make_train`; brax: before `ppo.train`), compile included. `t_run_s`: `t_s` minus the
time JAX spent tracing, lowering and compiling until then (`CompileClock`: the union of
the time spans of the `/jax/core/compile/*` events that `jax.monitoring` reports, so
nested traces count once). The same clock serves both sides. It matters for brax:
brax 0.14.2 under JAX 0.10 compiles its training epoch a second time during the second
epoch (the same program: with a persistent compilation cache the second compile is a
cache hit; why JAX's in-memory cache misses was not investigated), which this excludes
like the first compile (`compile_after_first_call_s` shows it). `first_call_overhead_s`
is what the first call cost beyond the steady-state rate after the subtraction (compile
work JAX does not report, warm-up), as a check. "Time to X mm" is `t_run_s` of the
first snapshot below X (granularity: one jitted call); env steps/s is the steady state
from the end of the first call to the end of the run on the `t_run_s` clock, so host
work between calls (taking the snapshots, brax's host loop) counts; brax's own
`training/sps` (epoch time only) is kept as `brax_reported_sps_median`.

brax 0.14.2 calls `jax.device_put_replicated`, which JAX 0.10 removed; importing
`mara_mjx.adapters.brax_env` provides JAX's documented drop-in replacement (and imports
mujoco.mjx quietly, before brax does), so this module imports it before brax.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import math
import sys
import time
from collections.abc import Callable
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import mara_mjx
from mara_mjx.bench.runner import BenchConfig, Study
from mara_mjx.ppo import PRESETS, EvalConfig, EvalResult, PPOConfig, make_policy, make_train
from mara_mjx.ppo.evaluation import make_evaluate
from mara_mjx.viz.plots import finish_figure

COMPILE_EVENTS = "/jax/core/compile/"  # jaxpr trace, MLIR lowering, backend compile
THRESHOLDS_MM = (5.0, 1.0)


# ------------------------------------------------------------------------- clocks
class CompileClock:
    """Wall-clock since construction, with and without JAX's compile time (the union of
    the time spans of `/jax/core/compile/*` monitoring events). Use as a context manager
    so that the listener is removed afterwards."""

    def __init__(self) -> None:
        self.start = time.time()
        self._spans: list[tuple[float, float]] = []
        jax.monitoring.register_event_time_span_listener(self._listen)

    def _listen(self, event: str, start: float, end: float, **_: Any) -> None:
        if event.startswith(COMPILE_EVENTS):
            self._spans.append((start, end))

    def __enter__(self) -> CompileClock:
        return self

    def __exit__(self, *exc: Any) -> None:
        unregister = getattr(jax.monitoring, "unregister_event_time_span_listener", None)
        if unregister is not None:  # else the listener stays, harmlessly
            unregister(self._listen)

    def compile_s(self, until: float) -> float:
        """Seconds of compile between the start and `until` (overlapping spans once)."""
        total, reach = 0.0, self.start
        for start, end in sorted(self._spans):
            start, end = max(start, reach), min(end, until)
            if end > start:
                total += end - start
                reach = end
        return total

    def read(self) -> tuple[float, float]:
        """(seconds since start, seconds of compile among them)."""
        now = time.time()
        return now - self.start, self.compile_s(now)


# ------------------------------------------------------------------------- scorer
@dataclasses.dataclass(frozen=True)
class ScoreConfig:
    """The common scorer of policy snapshots (see the module docstring)."""

    episodes: int = 10
    steps: int = 100
    last: int = 10
    noise: float = 0.02
    seed: int = 0


def make_scorer(
    env: Any, act: Callable[[Any, jax.Array], jax.Array], config: ScoreConfig
) -> Callable[[Any], dict[str, jax.Array]]:
    """A jitted fn(p) -> errors of the deterministic policy `act(p, obs) -> joint targets`
    (obs (E, obs_size), targets (E, 6) rad) on `env`; `p` is traced, so one compile
    scores every snapshot. Returns settled_mm (mean |e| over the last `last` steps,
    episodes and axes), settled_axis_mm (3,), final_mm (last step) and best_mm (the
    lowest per-step mean)."""
    params = env.make_params(reset_noise=config.noise)
    keys = jax.random.split(jax.random.key(config.seed), config.episodes)
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step)

    def score(p: Any) -> dict[str, jax.Array]:
        def body(state, _):
            state = step(state, act(p, state.obs))
            return state, jnp.abs(state.metrics["position_error"])

        _, err = jax.lax.scan(body, reset(keys, params), None, length=config.steps)
        err = 1000.0 * err  # (T, E, 3) mm
        tail = err[-config.last :]
        return {
            "settled_mm": jnp.mean(tail),
            "settled_axis_mm": jnp.mean(tail, axis=(0, 1)),
            "final_mm": jnp.mean(err[-1]),
            "best_mm": jnp.min(jnp.mean(err, axis=(1, 2))),
        }

    return jax.jit(score)


def score_snapshots(run: Run, scorer: Callable[[Any], dict[str, jax.Array]]) -> None:
    """Fill `settled_mm` (and `settled_axis_mm`) of every curve point of `run`."""
    for point, snapshot in zip(run.curve, run.snapshots, strict=True):
        out = jax.device_get(scorer(snapshot))
        point["settled_mm"] = _num(out["settled_mm"])
        point["settled_axis_mm"] = [_num(x) for x in out["settled_axis_mm"]]


# --------------------------------------------------------------------------- runs
@dataclasses.dataclass
class Run:
    """One training run: a curve point and a host-side policy snapshot per jitted call
    (and one before training)."""

    impl: str
    task: str
    curve: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    snapshots: list[Any] = dataclasses.field(default_factory=list)
    wall_s: float = 0.0
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)

    def add(self, clock: CompileClock, env_steps: int, snapshot: Any, **values: Any) -> None:
        t_s, compile_s = clock.read()
        self.curve.append({"t_s": t_s, "compile_s": compile_s, "env_steps": env_steps, **values})
        self.snapshots.append(snapshot)

    def summary(self) -> dict[str, Any]:
        """Compile time, steady-state env steps/s and the time to each threshold of the
        error measures in the curve (JSON-ready; None where not reached). Sets each
        point's `t_run_s`: `t_s` minus the compile time until then."""
        c = self.curve
        for p in c:
            p["t_run_s"] = p["t_s"] - p["compile_s"]
        first = 1 if len(c) >= 3 else 0  # steady state from the end of the first call
        steps = c[-1]["env_steps"] - c[first]["env_steps"]
        seconds = c[-1]["t_run_s"] - c[first]["t_run_s"]
        sps = steps / seconds if seconds > 0 else None
        overhead = None
        if sps and len(c) >= 2:
            first_call = c[1]["t_run_s"] - c[0]["t_run_s"]
            overhead = first_call - (c[1]["env_steps"] - c[0]["env_steps"]) / sps
        out = {
            "impl": self.impl,
            "task": self.task,
            "env_steps": c[-1]["env_steps"],
            "calls": len(c) - 1,
            "compile_s": c[-1]["compile_s"],
            "compile_after_first_call_s": c[-1]["compile_s"] - c[min(1, len(c) - 1)]["compile_s"],
            "wall_s": self.wall_s,
            "run_s": c[-1]["t_run_s"],
            "env_steps_per_s": sps,
            "steady_state_from_first_call": first == 0,
            "first_call_overhead_s": overhead,
        }
        for key in ("det_error_mm", "settled_mm"):
            values = [p.get(key) for p in c if p.get(key) is not None]
            if not values:
                continue
            out[f"final_{key}"] = values[-1]
            out[f"best_{key}"] = min(values)
            for mm in THRESHOLDS_MM:
                hit = next((p for p in c if (p.get(key) is not None and p[key] < mm)), None)
                name = f"{key.removesuffix('_mm')}_to_{mm:g}mm"
                out[f"{name}_s"] = hit["t_run_s"] if hit else None
                out[f"{name}_wall_s"] = hit["t_s"] if hit else None
                out[f"{name}_env_steps"] = hit["env_steps"] if hit else None
        return {**out, **self.extra, "curve": c}


def train_ours(
    env: Any, task: str, config: PPOConfig, updates_per_call: int, progress: bool = True
) -> tuple[Run, Any]:
    """Our PPO on `env`; returns the run (curve with det_error_mm per call, policy
    snapshots on the host) and the final training state."""
    with CompileClock() as clock:
        run = Run("ours (mara_mjx.ppo)", task)
        trainer = make_train(env, config, updates_per_call)
        state = trainer.init(jax.random.key(config.seed))
        run.add(clock, 0, jax.device_get(make_policy(state, config)))
        done, per_update = 0, trainer.steps_per_update
        bar = tqdm(
            total=trainer.num_updates * per_update,
            unit="step",
            unit_scale=True,
            desc=f"ours {task}",
            disable=not progress,
            file=sys.stderr,
        )
        while done < trainer.num_updates:
            n = min(trainer.updates_per_call, trainer.num_updates - done)
            state, metrics = trainer.run(state, n)
            metrics = jax.device_get(metrics)
            snapshot = jax.device_get(make_policy(state, config))
            done += n
            valid = np.asarray(metrics["valid"], bool)
            det = np.asarray(metrics.get("det_error_mm", np.full(valid.shape, np.nan)))[valid]
            run.add(
                clock,
                done * per_update,
                snapshot,
                det_error_mm=_num(det[-1]),
                det_error_min_mm=_num(np.min(det)),
                distance_mm=_num(np.asarray(metrics.get("distance_mm", [np.nan]))[valid][-1]),
            )
            bar.update(n * per_update)
            bar.set_postfix(det_mm=f"{det[-1]:.2f}", refresh=False)
        bar.close()
        run.wall_s = clock.read()[0]
    return run, state


def brax_kwargs(config: PPOConfig, episode_length: int) -> dict[str, Any]:
    """brax `ppo.train` arguments matching `config` as closely as brax allows.

    Matched: envs, unroll length (= num_steps), minibatches and their size (brax's
    `batch_size` counts unrolls: num_envs / num_minibatches of num_steps steps = our
    minibatch), epochs, learning rate, discount, GAE lambda, policy clip, value clip
    (`clipping_epsilon_value` = clip_eps when clip_value), value coefficient, entropy
    cost (0 in the default preset: no entropy bonus on either side), gradient-norm clip,
    advantage normalisation, observation normalisation, reward scaling, separate tanh
    MLPs of `hidden_sizes` for policy and value, state-independent noise, seed, horizon.
    Not matchable (brax's own; `unmatched` lists our values): a constant learning rate
    (ours: `lr_schedule`, linear to 0 in the default preset), Adam eps 1e-8 (ours 1e-5),
    absolute actions, a tanh-squashed Gaussian in [-1, 1] mapped to the joint box by the
    adapter (ours: a Gaussian on joint targets in rad, in the default preset relative to
    the current joint positions, `relative_actions`), brax's noise parametrisation
    (softplus scale, init 1, floor 0.001) and lecun-uniform initialisation (ours: a
    log-std with `init_log_std` and `log_std_floor`, orthogonal), no clipping of
    normalised observations (ours: +-`obs_clip`), and truncation handled by masking in
    GAE (ours: bootstrap from the final obs)."""
    import flax.linen as nn

    import mara_mjx.adapters.brax_env  # noqa: F401  (before brax: quiet mujoco.mjx, JAX shim)

    # isort: split
    from brax.training.agents.ppo import networks as ppo_networks

    if config.num_envs % config.num_minibatches:
        raise ValueError(
            f"brax needs num_envs ({config.num_envs}) divisible by num_minibatches "
            f"({config.num_minibatches}): its minibatch is a whole number of unrolls"
        )
    factory = functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=tuple(config.hidden_sizes),
        value_hidden_layer_sizes=tuple(config.hidden_sizes),
        activation=nn.tanh,
    )
    return {
        "num_envs": config.num_envs,
        "episode_length": episode_length,
        "unroll_length": config.num_steps,
        "batch_size": config.num_envs // config.num_minibatches,
        "num_minibatches": config.num_minibatches,
        "num_updates_per_batch": config.update_epochs,
        "learning_rate": config.learning_rate,
        "discounting": config.gamma,
        "gae_lambda": config.gae_lambda,
        "clipping_epsilon": config.clip_eps,
        "clipping_epsilon_value": config.clip_eps if config.clip_value else None,
        "vf_loss_coefficient": config.vf_coef,
        "entropy_cost": config.ent_coef,
        "max_grad_norm": config.max_grad_norm,
        "normalize_advantage": config.normalize_advantages,
        "normalize_observations": config.normalize_obs,
        "reward_scaling": config.reward_scale,
        "network_factory": factory,
        "seed": config.seed,
    }


def unmatched(config: PPOConfig) -> dict[str, Any]:
    """Our values of the PPOConfig fields brax has no equivalent for (see brax_kwargs)."""
    names = ("lr_schedule", "adam_eps", "relative_actions", "init_log_std", "log_std_floor")
    names += ("obs_clip",)
    d = config.to_dict()
    return {name: d[name] for name in names if name in d}


def train_brax(
    task: str,
    config: PPOConfig,
    updates_per_call: int,
    episode_length: int,
    progress: bool = True,
) -> tuple[Run, Callable[[Any, jax.Array], jax.Array]]:
    """brax's PPO on `make_brax_env(task)`, `config.num_updates` updates of the same
    batch as ours, one epoch (= snapshot) per `updates_per_call` updates. Returns the run
    and act(params, obs) -> joint targets (the deterministic brax policy, mapped)."""
    from mara_mjx.adapters.brax_env import make_brax_env  # before brax: see the module docstring

    # isort: split
    from brax.training.agents.ppo import train as brax_ppo

    if config.num_updates % updates_per_call:
        raise ValueError(
            f"brax: {config.num_updates} updates are not a multiple of updates_per_call="
            f"{updates_per_call}; choose --total so that both sides do the same env steps"
        )
    benv = make_brax_env(task, episode_length=episode_length)
    calls = config.num_updates // updates_per_call
    total = config.num_updates * config.batch_size
    holder: dict[str, Any] = {}
    bar = tqdm(
        total=total,
        unit="step",
        unit_scale=True,
        desc=f"brax {task}",
        disable=not progress,
        file=sys.stderr,
    )

    with CompileClock() as clock:
        run = Run("brax ppo", task)
        brax_metrics: list[dict[str, float]] = []

        def policy_params_fn(step: int, make_policy: Any, params: Any) -> None:
            holder["make_policy"] = make_policy
            run.add(clock, int(step), jax.device_get(params))
            bar.update(int(step) - bar.n)

        def progress_fn(step: int, metrics: dict[str, Any]) -> None:
            brax_metrics.append(
                {k: float(v) for k, v in metrics.items() if k.startswith("training/")}
            )

        brax_ppo.train(
            environment=benv,
            num_timesteps=total,
            num_evals=calls + 1,
            run_evals=False,
            progress_fn=progress_fn,
            policy_params_fn=policy_params_fn,
            **brax_kwargs(config, episode_length),
        )
        run.wall_s = clock.read()[0]
    bar.close()
    sps = [m["training/sps"] for m in brax_metrics[1:] if "training/sps" in m]
    run.extra["brax_reported_sps_median"] = float(np.median(sps)) if sps else None
    if run.curve[-1]["env_steps"] != total:
        raise RuntimeError(f"brax ran {run.curve[-1]['env_steps']} env steps, ours {total}")
    make_brax_policy = holder["make_policy"]
    key = jax.random.PRNGKey(0)  # unused by the deterministic policy

    def act(params: Any, obs: jax.Array) -> jax.Array:
        action, _ = make_brax_policy(params, deterministic=True)(obs, key)
        return benv.to_joint_targets(action)

    return run, act


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
            brax_kwargs(config, self.episode_length)


@dataclasses.dataclass(frozen=True)
class BraxStudyConfig(TrainStudyConfig):
    """The brax study's settings (eval_episodes unused)."""

    study: ClassVar[str] = "brax"


def ppo_config(args: TrainStudyConfig) -> PPOConfig:
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
        per_call = args.updates_per_call * config.batch_size
        total = max(1, config.total_timesteps // per_call) * per_call
        if total != config.total_timesteps:
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
            "num_envs": config.num_envs,
            "updates_per_call": args.updates_per_call,
            "episode_length": args.episode_length,
            "ppo": config.to_dict(),
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
    kwargs = brax_kwargs(config, args.episode_length)
    kwargs_json = {k: v for k, v in kwargs.items() if k != "network_factory"}
    kwargs_json["network"] = (
        f"make_ppo_networks(policy and value {list(config.hidden_sizes)}, tanh)"
    )
    records = []
    for task in args.tasks:
        env = mara_mjx.make(task, max_episode_steps=args.episode_length)
        ours, _ = train_ours(env, task, config, args.updates_per_call)
        score_snapshots(ours, make_scorer(env, _act_ours, scoring))
        theirs, act = train_brax(task, config, args.updates_per_call, args.episode_length)
        score_snapshots(theirs, make_scorer(env, act, scoring))
        a, b = ours.summary(), theirs.summary()
        common = {"score": dataclasses.asdict(scoring), "num_envs": config.num_envs}
        b = {**b, **common, "brax_kwargs": kwargs_json, "unmatched": unmatched(config)}
        a = {**a, **common, "preset": args.preset, "ppo": config.to_dict()}
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
def _num(x: Any) -> float | None:
    """A float for JSON, None for NaN / inf / None."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


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
