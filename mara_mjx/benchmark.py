"""Measured throughput of mara_mjx: `python -m mara_mjx.benchmark STUDY [options]`.

Studies:
  env   env steps/s of the batched, jitted, auto-resetting step (`BatchedEnv.step`
        inside a `lax.scan`, random joint targets drawn inside the scan) for each task
        and driver over a sweep of environment counts. Compile time (first call) is
        reported apart from the steady state (median of `--repeats` timed calls after a
        warm-up). For the real driver, physics steps/s = env steps/s x substeps.
  peers C MuJoCo vs MJX on the same model, at each of `--peer-sizes` env counts.
        Train driver: C MuJoCo mj_kinematics + mj_collision for random joint targets
        in one process per CPU core (`mara_mjx/bench_cpeer.py`) against the env
        study's timing of the MJX train driver.
        Real driver:
        What is compared: the `real` driver's work. C side: `mujoco.rollout.rollout`
        (nthread = os.cpu_count(), one MjData per thread, persistent thread pool) of
        N arms x `--steps` env steps x 10 substeps of mj_step (5 ms, implicitfast,
        Newton, the model's contacts and position+velocity servos), open loop, with
        the controls the real driver would send: per env step uniform random joint
        targets, the servo reference moving toward them at `velocity` rad/s,
        ctrl = [ref, ref_vel] (built in numpy beforehand, not timed). MJX side: the
        `env` study's timing of `BatchedEnv.step` with the real driver (MARA task)
        for the same N and steps, which does the same 10 mjx.step substeps plus
        what C rollout does not: the final kinematics + collision for the pose,
        observation, reward, penetration checks and auto-reset. So the ratio
        MJX / C slightly favours C. Reported: env steps/s and physics steps/s (env
        steps x 10) of both, and MJX / C (env steps/s ratio) on the MJX row.
        `--skip-mjx` times the C sides only (the MJX real-driver compile takes about
        35 s on a CPU). The PPO peer is the `brax` study.
  train our PPO end to end on each task (`--preset`, default "default"; `--total`,
        `--num-envs`, ... override it): compile time apart, env steps/s including
        learning, and error (mm) against wall-clock after every jitted call of
        `--updates-per-call` updates, both the training metric `det_error_mm` and the
        common scorer's settled error; time to 5 mm and 1 mm; at the end the paper's
        evaluation (stop at 5 mm) and the same to the horizon. (`mara_mjx.bench_ppo`)
  brax  brax's PPO (`brax.training.agents.ppo`) on `make_brax_env(task)` against ours,
        same task, same env steps, hyperparameters from the same PPOConfig (as far as
        brax allows: `bench_ppo.brax_kwargs`). Both keep (wall-clock, params) snapshots
        during training; after training every snapshot is scored by one common scorer
        (the deterministic policy for `--score-steps` steps from `--score-episodes`
        noisy resets, mean per-axis error over the last `--score-last` steps). Reported:
        env steps/s during training, wall-clock to 5 mm and 1 mm (compile excluded),
        and the ratios. (`mara_mjx.bench_ppo`, whose docstring defines the clocks)
  limit FLOPs and bytes of one env step (XLA's cost analysis: estimates) against the
        device's ceilings measured in the same run (float32 HIGHEST and bfloat16
        matmul FLOP/s, elementwise memory bandwidth): the roofline bound on env
        steps/s, the measured env steps/s (as in `env`) and the fraction reached, for
        `--tasks` x `--drivers` x `--sizes` / `--real-sizes`. (`mara_mjx.bench_limit`)

scaling  env steps/s of the batched step and of PPO against the number of devices
        (1, 2, 4, ... all; weak scaling with a fixed per-device batch, and strong
        scaling of the default PPO batch), with the efficiency per added device
        (`mara_mjx/bench_scaling.py`). The other studies use every device the machine
        has (`BatchedEnv`'s default), so on a multi-GPU host their numbers are per host.

Output: a table on the terminal, and in `--out` (default runs/benchmarks/ under the working
directory; the recorded results are in benchmarks/results/):
  <study>.json (records + device, versions, settings, command), <study>.md, <study>.png.
`--quick` runs tiny sizes for a CPU smoke test. Matmuls run in float32 at HIGHEST
precision; XLA's non-deterministic (faster) GPU ops are used unless `--deterministic`.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import mara_mjx
from mara_mjx import bench_limit, bench_ppo, bench_scaling
from mara_mjx.envs.batched import BatchedEnv
from mara_mjx.plots import finish_figure
from mara_mjx.ppo import PRESETS
from mara_mjx.ppo.flags import configure_jax

# Relative to the working directory, never the package folder: a plain install must not
# write into site-packages, and a quick CPU run in a checkout must not replace the recorded
# results in benchmarks/results/ (name that folder with --out to update them).
DEFAULT_OUT = Path("runs") / "benchmarks"


def versions() -> dict[str, str]:
    import flax
    import mujoco
    import optax

    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": jax.lib.__version__ if hasattr(jax.lib, "__version__") else "",
        "mujoco": mujoco.__version__,
        "flax": flax.__version__,
        "optax": optax.__version__,
        "mara_mjx": mara_mjx.__version__,
    }


def device_info() -> dict[str, Any]:
    dev = jax.devices()[0]
    return {
        "platform": dev.platform,
        "device_kind": dev.device_kind,
        "device_count": jax.device_count(),
        "host": platform.node(),
    }


def _peak_memory() -> int | None:
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use")


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
    task: str, driver: str, num_envs: int, steps: int, repeats: int, devices: int | None = None
) -> dict[str, Any]:
    """Compile time and steady-state env steps/s of one (task, driver, num_envs), the
    envs spread over `devices` (None: all, BatchedEnv's default)."""
    env = mara_mjx.make(task, driver=driver)
    benv = BatchedEnv(env, num_envs, devices=devices)
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
        "num_envs": num_envs,
        "steps_per_call": steps,
        "compile_s": max(first - median, 0.0),
        "first_call_s": first,
        "median_call_s": median,
        "env_steps_per_s": sps,
        "physics_steps_per_s": sps * env.n_substeps if driver == "real" else None,
        "collision_fraction": float(collided),
        "peak_device_bytes": _peak_memory(),
    }


def env_study(args: argparse.Namespace) -> list[dict[str, Any]]:
    records = []
    for driver in args.drivers:
        sizes = args.sizes if driver == "train" else args.real_sizes
        for task in args.tasks:
            for n in sizes:
                try:
                    rec = time_env(task, driver, n, args.steps, args.repeats)
                except Exception as e:  # out of memory at the top of a sweep ends it
                    if "RESOURCE_EXHAUSTED" not in str(e) and "out of memory" not in str(e):
                        raise
                    print(f"{task} {driver} n={n}: out of device memory, sweep stops")
                    break
                records.append(rec)
                print(
                    f"{task:20s} {driver:5s} n={n:>7d}"
                    f"  {rec['env_steps_per_s'] / 1e6:9.3f} M steps/s"
                    f"  compile {rec['compile_s']:6.1f} s",
                    flush=True,
                )
    return records


def c_rollout_inputs(
    env: Any, num_envs: int, steps: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Initial states (num_envs, nstate) and controls (num_envs, steps * substeps, 12)
    for `mujoco.rollout` equivalent to the MJX real driver: each env step draws uniform
    joint targets in the joint box; over its `n_substeps` physics steps the servo
    reference moves toward them at `velocity` rad/s, ctrl = [ref (6), ref_vel (6)]
    as in `Arm.real_step`. The arm starts at rest at q = 0."""
    import mujoco

    m = env.arm.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, state0, spec)
    rng = np.random.default_rng(seed)
    dt, n_sub = env.arm.timestep, env.n_substeps
    max_move = env.config.velocity * dt
    ref = np.zeros((num_envs, 6))
    ctrl = np.empty((num_envs, steps * n_sub, 12))
    for t in range(steps):
        command = rng.uniform(env.joint_lower, env.joint_upper, (num_envs, 6))
        for k in range(n_sub):
            move = np.clip(command - ref, -max_move, max_move)
            ref = ref + move
            ctrl[:, t * n_sub + k, :6] = ref
            ctrl[:, t * n_sub + k, 6:] = move / dt
    return np.tile(state0, (num_envs, 1)), ctrl


def time_c_rollout(
    env: Any, num_envs: int, steps: int, repeats: int, nthread: int
) -> dict[str, Any]:
    """Steady-state env steps/s of C MuJoCo `mujoco.rollout.rollout` on `nthread` CPU
    threads (one MjData each) for `num_envs` arms x `steps` env steps (x substeps)."""
    import mujoco
    from mujoco import rollout

    m = env.arm.mj_model
    datas = [mujoco.MjData(m) for _ in range(nthread)]
    state0, ctrl = c_rollout_inputs(env, num_envs, steps)
    nstep = ctrl.shape[1]
    state_out = np.empty((num_envs, nstep, state0.shape[1]))
    sensor_out = np.empty((num_envs, nstep, m.nsensordata))

    def call() -> float:
        t0 = time.perf_counter()
        rollout.rollout(
            m,
            datas,
            state0,
            ctrl,
            control_spec=mujoco.mjtState.mjSTATE_CTRL,
            state=state_out,
            sensordata=sensor_out,
            persistent_pool=True,
        )
        return time.perf_counter() - t0

    first = call()
    median = statistics.median(call() for _ in range(repeats))
    sps = num_envs * steps / median
    return {
        "impl": f"mujoco C rollout ({nthread} threads)",
        "device": f"cpu x{nthread}",
        "num_envs": num_envs,
        "steps_per_call": steps,
        "substeps": env.n_substeps,
        "first_call_s": first,
        "median_call_s": median,
        "env_steps_per_s": sps,
        "physics_steps_per_s": sps * env.n_substeps,
        "collision_fraction": None,
        "mjx_over_c": None,
    }


def peers_study(args: argparse.Namespace) -> list[dict[str, Any]]:
    """C MuJoCo vs MJX, same env counts, same run: the train driver's work (kinematics +
    collision, `bench_cpeer`) and the real driver's (`mujoco.rollout`); `--drivers`
    picks which."""
    import os

    from mara_mjx.bench_cpeer import KinematicsPool

    task = args.tasks[0]
    env = mara_mjx.make(task, driver="real")
    nthread = os.cpu_count() or 1
    records = []

    def compare(driver: str, n: int, c: dict[str, Any]) -> None:
        """Record C's timing `c` and (unless --skip-mjx) MJX's for the same driver and n."""
        records.append(c)
        line = f"n={n:>7d} {driver} driver: C {c['env_steps_per_s'] / 1e6:8.3f} M/s"
        if not args.skip_mjx:
            mj = time_env(task, driver, n, args.steps, args.repeats)
            ratio = mj["env_steps_per_s"] / c["env_steps_per_s"]
            impl = f"mjx {driver} driver (BatchedEnv.step)"
            records.append(
                {"impl": impl, "device": device_info()["device_kind"], **mj, "mjx_over_c": ratio}
            )
            line += f"  MJX {mj['env_steps_per_s'] / 1e6:8.3f} M/s  MJX/C {ratio:.2f}x"
        print(line, flush=True)

    if "train" in args.drivers:
        pool = KinematicsPool(env.arm.mj_model, nthread)
        try:
            for n in args.peer_sizes:
                compare("train", n, pool.time(n, args.steps, args.repeats))
        finally:
            pool.close()
    if "real" in args.drivers:
        for n in args.peer_sizes:
            compare("real", n, time_c_rollout(env, n, args.steps, args.repeats, nthread))
    return records


STUDIES = {
    "env": env_study,
    "peers": peers_study,
    "train": bench_ppo.train_study,
    "brax": bench_ppo.brax_study,
    "limit": bench_limit.limit_study,
    "scaling": bench_scaling.scaling_study,
}


def _fmt_m(x: float | None) -> str:
    """Millions with two decimals, or '' for None."""
    return "" if x is None else f"{x / 1e6:.2f} M"


# Per study: title, markdown columns (header, record -> text), optional notes (records ->
# markdown lines under the table), and either plot(records, title, path) or, for the
# default plot of env steps/s vs env count, series (record -> label) and style (record
# -> line style).
STUDY_TABLES: dict[str, dict[str, Any]] = {
    "env": {
        "title": "env study: batched step throughput",
        "columns": [
            ("task", lambda r: r["task"]),
            ("driver", lambda r: r["driver"]),
            ("envs", lambda r: f"{r['num_envs']:,}"),
            ("env steps/s", lambda r: _fmt_m(r["env_steps_per_s"])),
            ("physics steps/s", lambda r: _fmt_m(r["physics_steps_per_s"])),
            ("compile (s)", lambda r: f"{r['compile_s']:.1f}"),
        ],
        "series": lambda r: f"{r['task']} ({r['driver']})",
        "style": lambda r: "-" if r["driver"] == "train" else "--",
    },
    "peers": {
        "title": "peers study: C MuJoCo (all CPU cores) vs MJX, train-driver and real-driver work",
        "columns": [
            ("implementation", lambda r: r["impl"]),
            ("device", lambda r: r["device"]),
            ("envs", lambda r: f"{r['num_envs']:,}"),
            ("env steps/s", lambda r: _fmt_m(r["env_steps_per_s"])),
            ("physics steps/s", lambda r: _fmt_m(r["physics_steps_per_s"])),
            (
                "MJX / C",
                lambda r: "" if r.get("mjx_over_c") is None else f"{r['mjx_over_c']:.2f}x",
            ),
        ],
        "series": lambda r: r["impl"],
        "style": lambda r: "-" if r["impl"].startswith("mjx") else "--",
    },
    "train": bench_ppo.TRAIN_TABLE,
    "brax": bench_ppo.BRAX_TABLE,
    "limit": bench_limit.LIMIT_TABLE,
    "scaling": bench_scaling.SCALING_TABLE,
}


def write_results(
    study: str, records: list[dict[str, Any]], out: Path, meta: dict[str, Any]
) -> list[Path]:
    """Write `<study>.json` (meta + records; NaN and infinities as null, so strict JSON),
    `<study>.md` (table and notes) and `<study>.png` (the study's plot; by default env
    steps/s vs environments, log-log) into `out`. Returns the written paths."""
    spec = STUDY_TABLES[study]
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{study}.{ext}" for ext in ("json", "md", "png")]
    data = _json_safe({**meta, "records": records})
    paths[0].write_text(json.dumps(data, indent=2, allow_nan=False))
    headers = [h for h, _ in spec["columns"]]
    lines = [
        f"# {spec['title']}",
        "",
        f"Device: {meta['device']['device_kind']} ({meta['device']['platform']}); "
        f"versions: jax {meta['versions']['jax']}, mujoco {meta['versions']['mujoco']}.",
        "",
        f"Command: `{meta['command']}`",
        "",
        "| " + " | ".join(headers) + " |",
        "|" + "|".join("---" for _ in headers) + "|",
    ]
    for r in records:
        lines.append("| " + " | ".join(f(r) for _, f in spec["columns"]) + " |")
    if "notes" in spec:
        lines += ["", *spec["notes"](records)]
    paths[1].write_text("\n".join(lines) + "\n")
    title = f"{study}: {meta['device']['device_kind']}"
    if "plot" in spec:
        spec["plot"](records, title, paths[2])
    else:
        plot_throughput(records, spec, title, paths[2])
    return paths


def _json_safe(x: Any) -> Any:
    """x with non-finite floats replaced by None (recursively through dicts and lists)."""
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_json_safe(v) for v in x]
    if isinstance(x, float | np.floating):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def plot_throughput(
    records: list[dict[str, Any]], spec: dict[str, Any], title: str, path: Path
) -> None:
    """env steps/s vs environments (log-log), one line per spec["series"] label."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label in sorted({spec["series"](r) for r in records}):
        rs = [r for r in records if spec["series"](r) == label]
        ax.plot(
            [r["num_envs"] for r in rs],
            [r["env_steps_per_s"] for r in rs],
            marker="o",
            linestyle=spec["style"](rs[0]),
            label=label,
        )
    ax.set_xscale("log")
    ax.set_yscale("log")
    finish_figure(fig, ax, path, title, "environments", "env steps / s")


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m mara_mjx.benchmark",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("study", choices=sorted(STUDIES), help="which study to run")
    p.add_argument("--tasks", nargs="+", default=list(mara_mjx.registered()))
    p.add_argument("--drivers", nargs="+", default=["train", "real"], choices=["train", "real"])
    p.add_argument(
        "--sizes",
        nargs="+",
        type=int,
        default=[1024, 16384, 65536],
        help="environment counts for the train driver",
    )
    p.add_argument(
        "--real-sizes",
        nargs="+",
        type=int,
        default=[16384],
        help="environment counts for the real driver",
    )
    p.add_argument(
        "--peer-sizes",
        nargs="+",
        type=int,
        default=[256, 1024, 4096],
        help="environment counts for the peers study (C rollout and MJX real driver)",
    )
    p.add_argument(
        "--skip-mjx",
        action="store_true",
        help="peers: time the C rollout only (the MJX real-driver compile takes ~35 s on CPU)",
    )
    p.add_argument(
        "--matmul-size",
        type=int,
        default=8192,
        help="limit: n of the n x n matmuls that measure peak FLOP/s",
    )
    p.add_argument(
        "--copy-size",
        type=int,
        default=2**29,
        help="limit: float32 elements of the x + 1 that measures memory bandwidth",
    )
    scaling = p.add_argument_group("scaling study")
    scaling.add_argument(
        "--device-counts", type=int, nargs="+", help="device counts (default 1, 2, 4, ... all)"
    )
    scaling.add_argument(
        "--scaling-envs", type=int, default=16384, help="env part: environments per device"
    )
    ppo = p.add_argument_group("train and brax studies (PPO)")
    ppo.add_argument("--preset", choices=sorted(PRESETS), default="default")
    ppo.add_argument("--total", type=int, help="env steps per run (default: the preset's)")
    for name in ("num-envs", "num-steps", "num-minibatches", "update-epochs", "seed"):
        ppo.add_argument(f"--{name}", type=int, help="override of the preset's field")
    ppo.add_argument(
        "--updates-per-call",
        type=int,
        default=16,
        help="PPO updates per jitted call = per curve point (brax: per epoch)",
    )
    ppo.add_argument(
        "--episode-length", type=int, default=1024, help="horizon of training episodes"
    )
    ppo.add_argument("--score-episodes", type=int, default=10, help="scorer: episodes")
    ppo.add_argument("--score-steps", type=int, default=100, help="scorer: steps per episode")
    ppo.add_argument(
        "--score-last", type=int, default=10, help="scorer: error averaged over the last steps"
    )
    ppo.add_argument(
        "--eval-episodes", type=int, default=10, help="train: episodes of the final evaluations"
    )
    p.add_argument(
        "--deterministic",
        action="store_true",
        help="deterministic XLA GPU ops (reproducible, about half the PPO speed); off by "
        "default, for speed; matmuls are float32 at HIGHEST precision either way",
    )
    p.add_argument("--steps", type=int, default=100, help="env steps per timed call")
    p.add_argument("--repeats", type=int, default=5, help="timed calls after the first")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="results folder")
    p.add_argument("--quick", action="store_true", help="tiny sizes: a CPU smoke run")
    args = p.parse_args(argv)
    unknown = sorted(set(args.tasks) - set(mara_mjx.registered()))
    if unknown:
        p.error(f"unknown task(s) {unknown}; registered: {list(mara_mjx.registered())}")
    if (
        min(args.sizes + args.real_sizes + args.peer_sizes) < 1
        or args.steps < 1
        or args.repeats < 1
    ):
        p.error("--sizes, --real-sizes, --steps and --repeats must be positive")
    positive = [
        "updates_per_call",
        "episode_length",
        "score_episodes",
        "score_steps",
        "score_last",
        "eval_episodes",
        "matmul_size",
        "copy_size",
    ]
    bad = [n for n in positive if getattr(args, n) < 1]
    if bad:
        p.error(f"{', '.join('--' + n.replace('_', '-') for n in bad)} must be positive")
    if args.score_last > args.score_steps:
        p.error("--score-last must not exceed --score-steps")
    if args.scaling_envs < 1 or any(n < 1 for n in args.device_counts or []):
        p.error("--scaling-envs and --device-counts must be positive")
    if args.quick:
        args.sizes, args.real_sizes, args.peer_sizes = [4], [4], [4]
        args.steps, args.repeats = 4, 1
        args.matmul_size, args.copy_size = 256, 2**20
        args.total, args.num_envs, args.num_steps = 64, 4, 8
        args.num_minibatches, args.update_epochs, args.updates_per_call = 2, 2, 1
        args.episode_length, args.eval_episodes = 16, 2
        args.score_episodes, args.score_steps, args.score_last = 2, 8, 4
    if args.study in ("train", "brax"):
        try:
            config = bench_ppo.ppo_config(args)
            if args.study == "brax":
                bench_ppo.brax_kwargs(config, args.episode_length)
        except ValueError as e:
            p.error(str(e))
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        probe = args.out / ".write_test"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        p.error(f"output folder {args.out} is not writable: {e}")
    if args.quick and not recorded_quick(args.out / f"{args.study}.json"):
        p.error(
            f"{args.out / (args.study + '.json')} holds a full (not --quick) run; a --quick "
            "smoke run does not replace it: choose another --out"
        )
    return args


def recorded_quick(path: Path) -> bool:
    """True if `path` (a study's JSON) does not exist or was itself a --quick run."""
    if not path.exists():
        return True
    try:
        return bool(json.loads(path.read_text()).get("config", {}).get("quick"))
    except (OSError, ValueError, AttributeError):
        return False


def configure(deterministic: bool) -> dict[str, str]:
    """Before the backend starts: float32 matmuls at HIGHEST precision (unless
    JAX_DEFAULT_MATMUL_PRECISION says otherwise) and, unless `deterministic` or XLA_FLAGS
    says otherwise, XLA's faster non-deterministic GPU ops (the training CLI's default is
    the reverse; `configure_jax` is shared). Returns what is in effect, for the JSON."""
    import os

    flags = os.environ.get("XLA_FLAGS", "")
    if not deterministic and "xla_gpu_deterministic_ops" not in flags:
        os.environ["XLA_FLAGS"] = (flags + " --xla_gpu_deterministic_ops=false").strip()
    configure_jax()
    return {
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
        "matmul_precision": str(jax.config.jax_default_matmul_precision),
    }


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    settings = configure(args.deterministic)
    if args.study == "scaling":  # needs the backend, so after configure; before any compile
        try:
            bench_scaling.device_counts(args.device_counts)
        except ValueError as e:
            print(f"python -m mara_mjx.benchmark: error: {e}", file=sys.stderr)
            sys.exit(2)  # as argparse's errors
    meta = {
        "study": args.study,
        "command": "python -m mara_mjx.benchmark "
        + " ".join(sys.argv[1:] if argv is None else argv),
        "versions": versions(),
        "device": device_info(),
        "settings": settings,
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    records = STUDIES[args.study](args)
    paths = write_results(args.study, records, args.out, meta)
    print(paths[1].read_text())
    print("wrote " + ", ".join(str(p) for p in paths))


if __name__ == "__main__":
    main()
