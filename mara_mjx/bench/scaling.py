"""The `scaling` study of `python -m mara_mjx.benchmark`: throughput against devices.

For every device count n in 1, 2, 4, ... up to the devices present (`--device_counts`
to choose), on the first of `--tasks` (train driver):

env   the batched env step (`BatchedEnv(..., devices=n)`, the env study's random-action
      `lax.scan`), weak scaling: `--envs_per_device` environments *per device*, so the
      global batch grows with n. Compile time apart; steady state = median of
      `--repeats` calls.
ppo   our PPO (`make_train(..., devices=n)`, the default preset), weak scaling: the
      default 2048 envs x 32 steps *per device* (global num_envs = 2048 n, minibatch
      count unchanged, so minibatches grow with n), and strong scaling: the default
      global batch (2048 envs) split over n devices. env steps/s of `Trainer.run`
      (`--updates_per_call` updates per call), steady state after a compile call.

Scaling efficiency of n devices = rate(n) / (n rate(1)) for weak scaling, and the same
formula for strong scaling (the ideal is n times faster on the same batch). Sharding is
`mara_mjx.runtime.sharding`: environments along one mesh axis, parameters replicated, SGD per
device on its own envs' samples with one gradient all-reduce per minibatch.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from typing import Any, ClassVar

import jax

import mara_mjx
from mara_mjx.bench.runner import BenchConfig, Study
from mara_mjx.viz.plots import finish_figure


@dataclasses.dataclass(frozen=True)
class ScalingConfig(BenchConfig):
    """The scaling study's settings."""

    device_counts: tuple[int, ...] = ()
    """Device counts to measure (empty: 1, 2, 4, ... and all)."""
    envs_per_device: int = 16384
    """Env part: environments per device."""
    updates_per_call: int = 10
    """PPO part: updates per timed call."""
    steps: int = 100
    """Env part: env steps per timed call."""
    repeats: int = 5
    """Timed calls after the first."""

    QUICK: ClassVar[dict[str, Any]] = {
        "envs_per_device": 64,
        "updates_per_call": 1,
        "steps": 4,
        "repeats": 1,
    }
    POSITIVE: ClassVar[tuple[str, ...]] = (
        "device_counts",
        "envs_per_device",
        "updates_per_call",
        "steps",
        "repeats",
    )

    def check_devices(self) -> None:
        """ValueError if a device count exceeds the devices present (needs the backend)."""
        device_counts(list(self.device_counts))


def _plot(records: list[dict[str, Any]], title: str, path) -> None:
    """env steps/s against devices, one line per (part, scaling), with the ideal."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key in sorted({(r["part"], r["scaling"]) for r in records}):
        rs = sorted(
            (r for r in records if (r["part"], r["scaling"]) == key), key=lambda r: r["devices"]
        )
        line = ax.plot(
            [r["devices"] for r in rs],
            [r["env_steps_per_s"] for r in rs],
            marker="o",
            label=f"{key[0]} ({key[1]})",
        )[0]
        one = rs[0]["env_steps_per_s"] if rs[0]["devices"] == 1 else None
        if one:
            ax.plot(
                [r["devices"] for r in rs],
                [one * r["devices"] for r in rs],
                ":",
                color=line.get_color(),
                alpha=0.6,
            )
    ax.set_yscale("log")
    finish_figure(fig, ax, path, title, "devices (dotted: ideal n x one device)", "env steps / s")


def _eff(r: dict[str, Any]) -> str:
    return "" if r.get("efficiency") is None else f"{100 * r['efficiency']:.1f}%"


SCALING_TABLE = {
    "title": "scaling study: throughput against devices",
    "columns": [
        ("part", lambda r: r["part"]),
        ("scaling", lambda r: r["scaling"]),
        ("devices", lambda r: str(r["devices"])),
        ("envs (global)", lambda r: f"{r['num_envs']:,}"),
        ("compile (s)", lambda r: f"{r['compile_s']:.1f}"),
        ("env steps/s", lambda r: f"{r['env_steps_per_s'] / 1e6:.2f} M"),
        ("efficiency", _eff),
    ],
    "notes": lambda records: [
        "Efficiency = env steps/s with n devices / (n x with one device). weak: the "
        "per-device batch is fixed (env: per-device envs; ppo: 2048 envs x 32 steps per "
        "device); strong: the default global PPO batch (2048 envs) split over n devices."
    ],
    "plot": _plot,
}


def device_counts(requested: list[int] | None) -> list[int]:
    available = jax.device_count()
    if requested:
        bad = [n for n in requested if n < 1 or n > available]
        if bad:
            raise ValueError(
                f"--device_counts {bad} not available: this machine has {available} device(s)"
            )
        return sorted(set(requested))
    counts, n = [], 1
    while n <= available:
        counts.append(n)
        n *= 2
    if counts[-1] != available:
        counts.append(available)
    return counts


def _timed(call, repeats: int) -> tuple[float, float]:
    """(first call s, median of `repeats` later calls s); `call()` returns what to block on."""
    t0 = time.perf_counter()
    jax.block_until_ready(call())
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(call())
        times.append(time.perf_counter() - t0)
    return first, statistics.median(times)


def time_env_devices(task: str, per_device: int, devices: int, steps: int, repeats: int):
    from mara_mjx.bench.env import time_env

    record = time_env(task, "train", per_device * devices, steps, repeats, devices=devices)
    return {
        "part": "env",
        "scaling": "weak",
        "devices": devices,
        "per_device_envs": per_device,
        **record,
    }


def time_ppo_devices(task: str, config, devices: int, updates: int, repeats: int, scaling: str):
    from mara_mjx.ppo import make_train

    trainer = make_train(mara_mjx.make(task), config, updates_per_call=updates, devices=devices)
    box = {"state": trainer.init(jax.random.key(0))}

    def call():
        box["state"], metrics = trainer.run(box["state"], updates)
        return metrics["reward_mean"]

    first, median = _timed(call, repeats)
    return {
        "part": "ppo",
        "scaling": scaling,
        "task": task,
        "devices": devices,
        "num_envs": config.num_envs,
        "num_steps": config.num_steps,
        "num_minibatches": config.num_minibatches,
        "updates_per_call": updates,
        "compile_s": max(first - median, 0.0),
        "median_call_s": median,
        "env_steps_per_s": config.batch_size * updates / median,
    }


def add_efficiency(records: list[dict[str, Any]]) -> None:
    """efficiency = rate(n) / (n rate(1)) within each (part, scaling) series."""
    base = {(r["part"], r["scaling"]): r["env_steps_per_s"] for r in records if r["devices"] == 1}
    for r in records:
        one = base.get((r["part"], r["scaling"]))
        r["efficiency"] = r["env_steps_per_s"] / (r["devices"] * one) if one else None


def scaling_study(args: ScalingConfig) -> list[dict[str, Any]]:
    from mara_mjx.ppo import PRESETS

    task = args.tasks[0]
    counts = device_counts(list(args.device_counts))
    per_device, steps, repeats = args.envs_per_device, args.steps, args.repeats
    default = PRESETS["default"]
    if args.quick:
        default = default.replace(num_envs=8, num_steps=4, num_minibatches=2, update_epochs=1)
    updates = args.updates_per_call
    records = []
    for n in counts:
        print(f"scaling: {n} device(s)", flush=True)
        records.append(time_env_devices(task, per_device, n, steps, repeats))
        weak = default.replace(
            num_envs=default.num_envs * n,
            total_timesteps=max(default.total_timesteps, default.batch_size * n * updates),
        )
        records.append(time_ppo_devices(task, weak, n, updates, repeats, "weak"))
        if n > 1:
            records.append(time_ppo_devices(task, default, n, updates, repeats, "strong"))
    # strong scaling's 1-device point is the weak one (same config)
    records += [
        {**r, "scaling": "strong"} for r in records if r["part"] == "ppo" and r["devices"] == 1
    ]
    add_efficiency(records)
    return records


STUDY = Study("scaling", ScalingConfig, scaling_study, SCALING_TABLE, "throughput against devices")
