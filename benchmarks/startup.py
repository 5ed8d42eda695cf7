"""Where the seconds before the first PPO update go (in process, or the CLI's wall-clock).

Two measurements of `python -m mara_mjx.train --env ENV` (tiny settings by default):

* `phases` (in this process): the train CLI's steps one after the other, each timed
  from command start (this process's start, as the CLI counts it): imports, JAX setup,
  building the env (the MJX model; the IK reachability check timed apart), make_train,
  `trainer.init` and the first `trainer.run` call, each split by JAX's own monitoring
  events into tracing (jaxpr), lowering (to StableHLO) and XLA compile, and the final
  evaluation's compile + run.
* `cli` (a subprocess per run): the command itself, wall-clock from its start to the
  config print, to the first row of progress.csv (the first update done) and to its exit;
  `--repeat 2` runs it twice, the second time on the compilation cache the first wrote.

    PYTHONPATH=$PWD python benchmarks/startup.py phases --env MARACollisionOrient
    PYTHONPATH=$PWD python benchmarks/startup.py cli --repeat 2 --cache /tmp/jaxcache

`--size default` runs the default preset (2048 envs x 32 steps, two updates: a GPU's
start-up); extra flags after `--` go to the train CLI. Results: one JSON line per
measurement on stdout (and `--json PATH`).
"""

from __future__ import annotations

import time

_T0 = time.monotonic()

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
from pathlib import Path  # noqa: E402

TINY = [
    "--num_envs", "4",
    "--num_steps", "8",
    "--total_timesteps", "64",
    "--num_minibatches", "2",
    "--update_epochs", "1",
    "--max_episode_steps", "16",
    "--updates_per_call", "1",
    "--checkpoint_every", "1000",
    "--eval.episodes", "2",
]  # fmt: skip
# the default preset (2048 envs x 32 steps) for two updates: a GPU's start-up
DEFAULT = ["--total_timesteps", "131072", "--updates_per_call", "1", "--checkpoint_every", "1000"]
EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "compile_s",
}


def command_start() -> float:
    """time.monotonic() at this process's start (Linux /proc), else the module's import."""
    try:
        with open("/proc/self/stat") as f:
            ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return time.monotonic() - max(0.0, uptime - ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return _T0


def phases(env_name: str, extra: list[str], cache: str, overlap: bool) -> dict:
    start = command_start()
    rows: list[dict] = []
    totals = {v: 0.0 for v in EVENTS.values()}
    compiled: list[str] = []

    def mark(name: str, since: float) -> None:
        now = time.monotonic()
        row = {"phase": name, "s": round(now - since, 3), "at_s": round(now - start, 3)}
        row.update({k: round(v, 3) for k, v in totals.items() if v})
        big = sorted({f for f, d in compiled if d > 0.5})
        if big:
            row["compiled_over_0.5s"] = big
        rows.append(row)
        for k in totals:
            totals[k] = 0.0
        compiled.clear()
        print(json.dumps(row), flush=True)

    mark("python start to this script", start)
    t = time.monotonic()
    import jax
    import jax.monitoring

    from mara_mjx.cli import train as train_cli

    def listen(event: str, d: float, **kw) -> None:
        if event in EVENTS:
            totals[EVENTS[event]] += d
        if event.endswith("backend_compile_duration"):
            compiled.append((kw.get("fun_name", "?"), d))

    jax.monitoring.register_event_duration_secs_listener(listen)
    mark("imports (jax, mara_mjx.train)", t)
    t = time.monotonic()
    args = train_cli.build_parser().parse_args(
        ["--env", env_name, *extra, "--compilation_cache", cache]
    )
    train_cli.configure_jax(args.compilation_cache)
    plan = train_cli.resolve(args)
    mark("flags, JAX setup", t)

    import mara_mjx
    from mara_mjx.ppo import warmup
    from mara_mjx.ppo.evaluation import evaluate, make_evaluate
    from mara_mjx.ppo.policy import make_policy
    from mara_mjx.ppo.train import make_train

    t = time.monotonic()
    env = mara_mjx.make(plan.env_name, **{**plan.env_overrides, "check_target": False})
    mark("env construction without the IK check", t)
    t = time.monotonic()
    env._check_target(env.config)
    mark("IK reachability check", t)
    t = time.monotonic()
    trainer = make_train(  # the reach probe its own program, as the train CLI keeps it
        env, plan.config, plan.run.updates_per_call, plan.run.devices, probe_apart=True
    )
    mark("make_train", t)
    t = time.monotonic()
    key, evaluate_fn, background = jax.random.key(0), None, None
    if overlap:  # as the train CLI does (mara_mjx.ppo.warmup)
        evaluate_fn = make_evaluate(env, plan.eval)
        policy_of = lambda s: make_policy(s, plan.config)  # noqa: E731
        background = warmup.start(trainer, key, evaluate_fn, policy_of, min_cpus=1)
    state = jax.block_until_ready(trainer.init(key))
    mark("trainer.init (first call)" + (", trainer.run compiling beside it" if overlap else ""), t)
    if background is not None:
        t = time.monotonic()
        background.wait("run")
        background.wait("probe")
        mark("waiting for the background compiles of trainer.run and the reach probe", t)
    for which in ("first update (first call)", "second update"):
        t = time.monotonic()
        state, metrics = trainer.run(state, 1)
        if trainer.probe is not None:  # the reach probe, its own program (as the CLI)
            metrics = {**metrics, "reach_error_mm": trainer.probe(state, 1)}
        jax.device_get(metrics)
        mark(f"trainer.run and the reach probe, {which}", t)
    if background is not None:
        t = time.monotonic()
        background.wait()
        mark("waiting for the background compile of the evaluation", t)
    t = time.monotonic()
    evaluate(env, make_policy(state, plan.config), plan.eval, fn=evaluate_fn)
    mark("final evaluation (first call)", t)
    return {"mode": "phases", "env": env_name, "cache": cache, "overlap": overlap, "phases": rows}


def cli(env_name: str, extra: list[str], cache: str) -> dict:
    out = Path(tempfile.mkdtemp(prefix="startup-")) / "run"
    cmd = [sys.executable, "-m", "mara_mjx.train", "--env", env_name, *extra]
    cmd += ["--out", str(out), "--compilation_cache", cache, "--progress", "false"]
    start = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    times: dict[str, float] = {}
    lines = []

    def watch() -> None:  # the first row of progress.csv: the first update is done
        csv = out / "progress.csv"
        while proc.poll() is None and "first_update_s" not in times:
            if csv.exists() and len(csv.read_text().splitlines()) > 1:
                times["first_update_s"] = time.monotonic() - start
            time.sleep(0.1)

    threading.Thread(target=watch, daemon=True).start()
    for line in proc.stdout:  # type: ignore[union-attr]
        now = time.monotonic() - start
        lines.append(line)
        if line.startswith("{") and "config_s" not in times:
            times["config_s"] = now
        if "the first call compiles" in line:
            times["training_starts_s"] = now
        if line.startswith("time to "):
            times.setdefault("training_done_s", now)
    proc.wait()
    times["exit_s"] = time.monotonic() - start
    if proc.returncode != 0:
        raise SystemExit("".join(lines[-40:]))
    shutil.rmtree(out.parent, ignore_errors=True)
    return {"mode": "cli", "env": env_name, "cache": cache, "command": cmd[1:]} | {
        k: round(v, 2) for k, v in times.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mode", choices=("phases", "cli"))
    parser.add_argument("--env", default="MARACollisionOrient")
    parser.add_argument(
        "--cache", default="false", help="--compilation_cache of the runs (default: off)"
    )
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument(
        "--overlap",
        choices=("true", "false"),
        default="true",
        help="phases: compile trainer.run and the evaluation in the background as the "
        "train CLI does (false: one after the other, as before issue 14)",
    )
    parser.add_argument("--json", help="also append the results to this file")
    parser.add_argument("--overwrite", action="store_true", help="--json may append to any file")
    parser.add_argument(
        "--size",
        choices=("tiny", "default"),
        default="tiny",
        help="tiny: 4 envs x 8 steps (a CPU); default: the default preset, 2 updates (a GPU)",
    )
    args, extra = parser.parse_known_args()
    if args.json:  # a new file or this script's own earlier lines, checked before the work
        from mara_mjx.cli.common import UserError
        from mara_mjx.runtime import outputs

        try:
            outputs.check_lines_output(
                args.json, "--json file", "mode", ("phases", "cli"), args.overwrite
            )
        except UserError as e:
            raise SystemExit(f"error: {e}") from None
    extra = (TINY if args.size == "tiny" else DEFAULT) + [a for a in extra if a != "--"]
    for _ in range(args.repeat):
        if args.mode == "phases":
            result = phases(args.env, extra, args.cache, args.overlap == "true")
        else:
            result = cli(args.env, extra, args.cache)
        print(json.dumps(result), flush=True)
        if args.json:
            with open(args.json, "a") as f:
                f.write(json.dumps(result) + "\n")
        if args.mode == "phases":
            break  # in-process: a second run would reuse this process's caches


if __name__ == "__main__":
    main()
