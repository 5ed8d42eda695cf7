"""Timed PPO runs of the `train` and `brax` studies (`mara_mjx.bench.ppo`): the compile
clock, a run's curve of (wall-clock, env steps, error) points with a host-side policy
snapshot per point, our PPO's training loop and the common scorer of snapshots.

`train_ours` trains our PPO one jitted call at a time and adds a curve point and a
snapshot to its `Run` after each (brax's side, `mara_mjx.bench.brax_peer.train_brax`,
fills a `Run` the same way); after training, outside the timed region, `score_snapshots`
scores every snapshot of a run with one jitted `make_scorer`, and `Run.summary` turns the
curve into the study's record (compile time, steady-state env steps/s, time to 5 mm and
1 mm).

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
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from mara_mjx.ppo import PPOConfig, make_policy, make_train

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
        state = trainer.init(jax.random.key(trainer.config.ppo.seed))
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


def _num(x: Any) -> float | None:
    """A float for JSON, None for NaN / inf / None."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None
