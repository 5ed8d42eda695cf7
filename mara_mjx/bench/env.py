"""The `env` study: env steps/s of the batched, jitted, auto-resetting step.

`BatchedEnv.step` inside a `lax.scan`, random joint targets drawn inside the scan, for
each task and driver over a sweep of environment counts. Compile time (first call) is
reported apart from the steady state (median of `repeats` timed calls after a warm-up).
For the real driver, physics steps/s = env steps/s x substeps.
"""

from __future__ import annotations

import dataclasses
import itertools
import statistics
import time
from typing import Any, ClassVar, Literal

import jax
import jax.numpy as jnp

import mara_mjx
from mara_mjx.bench.runner import BenchConfig, Study, fmt_m, peak_memory
from mara_mjx.envs.base import KINEMATICS
from mara_mjx.envs.batched import BatchedEnv

DRIVERS = ("train", "real")


@dataclasses.dataclass(frozen=True)
class EnvStudyConfig(BenchConfig):
    """The env study's settings."""

    drivers: tuple[Literal["train", "real"], ...] = ("train", "real")
    """Drivers to measure."""
    sizes: tuple[int, ...] = (1024, 16384, 65536)
    """Environment counts for the train driver."""
    real_sizes: tuple[int, ...] = (16384,)
    """Environment counts for the real driver."""
    steps: int = 100
    """Env steps per timed call."""
    repeats: int = 5
    """Timed calls after the first."""
    kinematics: tuple[Literal["lean", "fused", "mjx"], ...] = ("lean",)
    """The arm's pose passes to measure (EnvConfig.kinematics): 'lean' (the default),
    'fused' (its scalar form, fewer kernels) or 'mjx'."""
    reset_strategies: tuple[Literal["select", "cond"], ...] = ("select",)
    """BatchedEnv's auto-reset strategies to measure: 'select' (the default) or 'cond'."""

    QUICK: ClassVar[dict[str, Any]] = {"sizes": (4,), "real_sizes": (4,), "steps": 4, "repeats": 1}
    POSITIVE: ClassVar[tuple[str, ...]] = ("sizes", "real_sizes", "steps", "repeats")
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {
        "drivers": DRIVERS,
        "kinematics": KINEMATICS,
        "reset_strategies": BatchedEnv.RESET_STRATEGIES,
    }


def variant(rec: dict[str, Any]) -> str:
    """A record's pose pass, and its reset strategy where not the default."""
    strategy = rec.get("reset_strategy", "select")
    return rec.get("kinematics", "lean") + ("" if strategy == "select" else f", {strategy}")


def make_step_body(benv: BatchedEnv):
    """One batched step with uniform random joint targets, as a `lax.scan` body:
    ((state, key), _) -> ((state, key), fraction of envs that collided). The env study
    times it; the limit study cost-analyses it."""
    lower, upper = jnp.asarray(benv.env.joint_lower), jnp.asarray(benv.env.joint_upper)

    def body(carry, _):
        state, key = carry
        key, action_key = jax.random.split(key)
        action = jax.random.uniform(action_key, (benv.num_envs, 6), minval=lower, maxval=upper)
        state = benv.step(state, action)
        return (state, key), state.metrics["collided"].mean()

    return body


def make_rollout(benv: BatchedEnv, steps: int):
    """A jitted function running `steps` batched steps with uniform random joint targets."""
    body = make_step_body(benv)

    @jax.jit
    def rollout(state, key):
        (state, key), collided = jax.lax.scan(body, (state, key), None, length=steps)
        return state, key, collided.mean()

    return rollout


def time_env(
    task: str,
    driver: str,
    num_envs: int,
    steps: int,
    repeats: int,
    devices: int | None = None,
    reset_strategy: str = "select",
    **overrides: Any,
) -> dict[str, Any]:
    """Compile time and steady-state env steps/s of one (task, driver, num_envs), the
    envs spread over `devices` (None: all, BatchedEnv's default) and reset by
    `reset_strategy`; `overrides`: further EnvConfig fields (e.g. real_contacts)."""
    env = mara_mjx.make(task, driver=driver, **overrides)
    benv = BatchedEnv(env, num_envs, reset_strategy=reset_strategy, devices=devices)
    rollout = make_rollout(benv, steps)
    state = jax.jit(benv.reset)(jax.random.key(0))
    key = jax.random.key(1)
    jax.block_until_ready(state)
    t0 = time.perf_counter()
    state, key, collided = jax.block_until_ready(rollout(state, key))
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state, key, collided = jax.block_until_ready(rollout(state, key))
        times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    sps = num_envs * steps / median
    return {
        "task": task,
        "driver": driver,
        "kinematics": env.config.kinematics,
        "reset_strategy": reset_strategy,
        "num_envs": num_envs,
        "steps_per_call": steps,
        "compile_s": max(first - median, 0.0),
        "first_call_s": first,
        "median_call_s": median,
        "env_steps_per_s": sps,
        "physics_steps_per_s": sps * env.n_substeps if driver == "real" else None,
        "collision_fraction": float(collided),
        "peak_device_bytes": peak_memory(),
    }


def env_study(args: EnvStudyConfig) -> list[dict[str, Any]]:
    records = []
    for driver in args.drivers:
        sizes = args.sizes if driver == "train" else args.real_sizes
        for task, kin, rs in itertools.product(args.tasks, args.kinematics, args.reset_strategies):
            for n in sizes:
                try:
                    rec = time_env(
                        task, driver, n, args.steps, args.repeats, reset_strategy=rs, kinematics=kin
                    )
                except Exception as e:  # out of memory at the top of a sweep ends it
                    if "RESOURCE_EXHAUSTED" not in str(e) and "out of memory" not in str(e):
                        raise
                    print(f"{task} {driver} n={n}: out of device memory, sweep stops")
                    break
                records.append(rec)
                print(
                    f"{task:20s} {driver:5s} {variant(rec):11s} n={n:>7d}"
                    f"  {rec['env_steps_per_s'] / 1e6:9.3f} M steps/s"
                    f"  compile {rec['compile_s']:6.1f} s",
                    flush=True,
                )
    return records


TABLE: dict[str, Any] = {
    "title": "env study: batched step throughput",
    "columns": [
        ("task", lambda r: r["task"]),
        ("driver", lambda r: r["driver"]),
        ("kinematics", variant),
        ("envs", lambda r: f"{r['num_envs']:,}"),
        ("env steps/s", lambda r: fmt_m(r["env_steps_per_s"])),
        ("physics steps/s", lambda r: fmt_m(r["physics_steps_per_s"])),
        ("compile (s)", lambda r: f"{r['compile_s']:.1f}"),
    ],
    "series": lambda r: f"{r['task']} ({r['driver']}, {variant(r)})",
    "style": lambda r: "-" if r["driver"] == "train" else "--",
}

STUDY = Study("env", EnvStudyConfig, env_study, TABLE, "batched env step throughput")
