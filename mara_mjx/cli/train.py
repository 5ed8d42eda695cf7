"""Train PPO on a MARA task: python -m mara_mjx.train --env MARACollisionOrient

    python -m mara_mjx.train --env MARA                          # the task's preset (GPU)
    python -m mara_mjx.train --env MARA --preset paper           # the paper: 1 env, 1e8 steps
    python -m mara_mjx.train --env MARA --preset cpu             # a laptop CPU: minutes
    python -m mara_mjx.train --env MARA --num_envs 4096 --learning_rate 1e-3 --driver train
    python -m mara_mjx.train --resume runs/MARA-20250101-120000  # continue exactly
    python -m mara_mjx.train --env MARA --seeds 5     # seeds 0..4, one program (cli/seeds.py)

Every field of TrainConfig's sections (PPOConfig, PolicyConfig, CurriculumConfig), RunConfig,
EvalConfig and the env's EnvConfig is a flag
(`--field` or `--section.field`; see --help). The run folder (--out, default
runs/<env>-<timestamp>) receives config.json, progress.csv (one row per update),
TensorBoard events (tb/), checkpoints (checkpoints/ckpt_<update>.npz), and at the end
eval.json (the paper's accuracy table), summary.json (final metrics and the wall-clock
time at which the deterministic mean per-axis error first dropped below 5 mm and 1 mm)
and plots/*.png.

Bad input (unknown env, invalid config, unwritable folder, missing or corrupt checkpoint,
an --out that is not a mara_mjx run folder, a run folder in use by another process, a
checkpoint of another run or task) fails before anything is compiled, with one line on
stderr and exit status 2; so does a write that fails (a full disk), naming the file.
Ctrl-C or SIGTERM (a scheduler's stop) finishes the jitted call in flight, writes a
checkpoint and exits with status 130 (Ctrl-C) or 143 (SIGTERM), as a shell reports a
process those signals kill (`--resume` continues; a second signal exits at once);
during the final evaluation they stop it, and `--resume` on the finished run evaluates
again. A folder with no checkpoint (a run killed before its first one) is started over by
the same command. What the run folder holds and which files the CLIs never replace:
`mara_mjx.runtime.runs`.
"""

# ruff: noqa: E402  (the clock starts before the heavy imports)
from __future__ import annotations

import os
import time


def _command_start(pid: int | str = "self") -> float:
    """time.monotonic() at the start of process `pid`, by default this one (Linux: from
    /proc, so the package imports count too), else now."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        age = uptime - start_ticks / os.sysconf("SC_CLK_TCK")
        return time.monotonic() - max(0.0, age)
    except (OSError, ValueError, IndexError):
        return time.monotonic()


_START = _command_start()  # "wall-clock since command start" counts from here

import argparse
import dataclasses
import functools
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
from tqdm import tqdm

import mara_mjx
from mara_mjx.cli import seeds
from mara_mjx.cli.common import (
    UserError,
    configure_jax,
    uses_real_driver,
)
from mara_mjx.cli.train_plan import Plan, build_parser, resolve
from mara_mjx.envs.mara import is_orient_task
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo import logger, warmup
from mara_mjx.ppo.divergence import check_finite
from mara_mjx.ppo.evaluation import PAPER_RESULTS, evaluate, format_table, make_evaluate
from mara_mjx.ppo.metrics import num_parameters
from mara_mjx.ppo.policy import make_policy
from mara_mjx.ppo.teacher import load_teacher
from mara_mjx.ppo.train import Trainer, make_train
from mara_mjx.runtime import distributed, files, runs, sharding

PROG = "mara_mjx.train"


def main(argv: list[str] | None = None) -> int:
    args = build_parser(argv).parse_args(argv)
    try:
        with runs.sigterm_as_interrupt():  # a scheduler's stop is handled as Ctrl-C
            return _main(args)
    except files.WriteError as e:
        run = runs.run_dir_of(Path(e.filename)) if e.filename else None
        resumable = run is not None and ckpt.list_checkpoints(run)
        again = f"--resume {run} continues the run" if resumable else "run the command again"
        raise UserError(
            f"cannot write {e.filename!r}: {e.strerror}; the files written before are whole "
            f"(every write is atomic): free some space (or fix the folder), then {again}"
        ) from e
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted", file=sys.stderr)
        return runs.exit_status()


def _main(args: argparse.Namespace) -> int:
    configure_jax(args.compilation_cache, uses_real_driver(args, args.resume))
    launch = distributed.launch_from(args)
    seeds.check_launch(getattr(args, "run.seeds", 1), args.resume, launch is not None)
    distributed.initialize(launch)  # several processes: see there
    plan = resolve(args)
    seeds.check(plan.run.seeds, plan.run.devices, jax.device_count())
    try:
        env = mara_mjx.make(plan.env_name, **plan.env_overrides)
    except ValueError as e:
        raise UserError(f"cannot build env {plan.env_name}: {e}") from e
    try:  # cheap (nothing is compiled yet): device and batch-divisibility errors first
        devices = 1 if plan.run.seeds > 1 else plan.run.devices  # seeds: see mara_mjx.cli.seeds
        teacher = None
        if plan.config.curriculum.teacher:  # imitation: the teacher of the student's seed
            # (--seeds: the first seed's, the program's template; seeds.train pairs them all)
            own = None if plan.run.seeds > 1 else plan.config.ppo.seed
            teacher = load_teacher(plan.config.curriculum.teacher, plan.env_name, own)
        trainer = make_train(  # a single run's reach probe: its own program (ppo.warmup)
            env, plan.config, plan.run.updates_per_call, devices, teacher, plan.run.seeds == 1
        )
    except ValueError as e:
        raise UserError(str(e)) from e
    # env-dependent fields resolved (quat_index): saved with every checkpoint, policies read alike
    plan = dataclasses.replace(plan, config=trainer.config)
    announce = functools.partial(_announce, plan, trainer, args.verbose)
    if plan.run.seeds > 1:
        host = seeds.Host(run_meta, finish, STOP, elapsed, announce)
        return seeds.train(plan, env, trainer, host)
    main_process = distributed.is_main()  # the one that writes the run folder
    lock = None  # the run folder's, held while this process writes there (mara_mjx.runtime.runs)
    try:
        if main_process:
            lock = runs.prepare_run_folder(plan.out, plan.checkpoint, plan.source_run)
        return _train(plan, env, trainer, main_process, announce)
    finally:
        if lock is not None:
            lock.release()


def _train(plan: Plan, env: Any, trainer: Trainer, main_process: bool, announce: Callable) -> int:
    """Training and the final evaluation, in a prepared (and locked) run folder."""
    progress: dict[str, Any] = {"update": 0, "env_steps": 0, "time_s": 0.0, "milestones": {}}
    state = None
    if plan.checkpoint is not None:
        arrays, meta = ckpt.load_checkpoint(plan.checkpoint)
        template = jax.eval_shape(trainer.init, jax.random.key(0))  # traced, not compiled
        state = ckpt.arrays_to_state(arrays, template)
        # where init puts it (envs sharded, the rest replicated): no second compile of run
        env_state = sharding.put(state.env_state, trainer.env.mesh, axis=0)
        state = sharding.put(state.replace(env_state=None), trainer.env.mesh)
        state = state.replace(env_state=env_state)
        progress = meta["progress"]

    meta = run_meta(plan, env)
    resolved = {**meta, "resume_from": str(plan.checkpoint) if plan.checkpoint else None}
    distributed.check_same_config(resolved, plan.checkpoint)
    if main_process:
        announce(resolved)
        runs.write_json(plan.out / "config.json", resolved)
    else:
        print(f"{distributed.describe()}: joined; process 0 writes the run folder", flush=True)

    orientation = is_orient_task(env)
    milestones = logger.Milestones(progress.get("milestones"))
    evaluate_fn = make_evaluate(env, plan.eval) if main_process and plan.run.evaluate else None
    log = distributed.NoLog(logger.columns(orientation))
    try:
        with STOP:  # Ctrl-C or SIGTERM: finish the call in flight, write a checkpoint, exit
            if main_process:  # (on resume it rewrites progress.csv: inside STOP, atomically)
                log = logger.RunLogger(
                    plan.out,
                    logger.columns(orientation),
                    plan.run.tensorboard,
                    resume_update=progress["update"] if plan.checkpoint else None,
                    resume_env_steps=progress["env_steps"],
                )
            trainer = warmup.traced(trainer, state, plan.config.ppo.seed)  # warm: no tracing
            if state is None:  # compile run (and the evaluation) while init compiles
                key = jax.random.key(plan.config.ppo.seed)
                warm = warmup.start(
                    trainer, key, evaluate_fn, lambda s: make_policy(s, plan.config)
                )
                state = trainer.init(key)
                if warm is not None:
                    warm.wait("run")
                    warm.wait("probe")
            if main_process:
                print(
                    f"{plan.env_name}: {trainer.num_updates} updates of {plan.config.ppo.num_envs} "
                    f"envs x {plan.config.ppo.num_steps} steps, {num_parameters(state.params)} "
                    f"parameters, {jax.default_backend()} backend; the first call compiles",
                    flush=True,
                )
            state, last = train_loop(trainer, state, plan, meta, progress, log, milestones)
    except KeyboardInterrupt:
        print(f"\n{runs.interrupted_message(plan.out)}", file=sys.stderr)
        return runs.exit_status()
    finally:
        log.close()
    state = distributed.gather(state)  # several processes: each gets the whole state
    try:
        if main_process:
            finish(env, state, plan, meta, last, milestones, evaluate_fn=evaluate_fn)
    except KeyboardInterrupt:
        print(
            "\ninterrupted during the final evaluation; training is complete and its last "
            f"checkpoint whole: --resume {plan.out} runs the evaluation (and writes the "
            "plots and summary) again",
            file=sys.stderr,
        )
        return runs.exit_status()
    finally:
        distributed.barrier("mara_mjx.train: finished", last=True)
    return 0


def _announce(plan: Plan, trainer: Trainer, verbose: bool, resolved: dict[str, Any]) -> None:
    """The run's header: task, preset, seeds, the batch, the device, the run folder; the
    whole resolved config with --verbose."""
    n = plan.run.seeds
    first = plan.config.ppo.seed
    who = f"seed {first}" if n == 1 else f"seeds {first}..{first + n - 1}"
    steps = trainer.num_updates * trainer.steps_per_update
    device = jax.devices()[0]
    if verbose:
        print(json.dumps(resolved, indent=2), flush=True)
    print(
        f"{plan.env_name}, preset {plan.preset or '(of the checkpoint)'}, {who}: "
        f"{plan.config.ppo.num_envs} envs x {plan.config.ppo.num_steps} steps per update, "
        f"{steps:,} env steps{' per seed' if n > 1 else ''}\n"
        f"device: {jax.device_count()} x {device.device_kind} ({device.platform}); "
        f"run folder: {plan.out} (config.json holds the whole config; --verbose prints it)",
        flush=True,
    )


def run_meta(plan: Plan, env: Any) -> dict[str, Any]:
    """The resolved config saved in config.json and with every checkpoint."""
    return {
        "env_name": plan.env_name,
        "preset": plan.preset,
        "env_config": env.config.to_dict(),
        "observation_size": env.observation_size,
        "action_size": env.action_size,
        **plan.config.to_dict(),  # "ppo", "policy", "curriculum"
        "run": plan.run.replace(out=str(plan.out)).to_dict(),
        "eval": plan.eval.to_dict(),
        **runs.provenance(),
    }


STOP = runs.StopRequest(
    "stopping after the jitted call in flight (the first one also compiles), then writing "
    "a checkpoint; press Ctrl-C (or send SIGTERM) again to stop at once, losing the updates "
    "since the last checkpoint"
)


def elapsed(progress_time: float, resumed: bool) -> float:
    """Seconds since command start, plus the run's time before the checkpoint."""
    return (progress_time if resumed else 0.0) + time.monotonic() - _START


def train_loop(
    trainer: Trainer,
    state: Any,
    plan: Plan,
    meta: dict[str, Any],
    progress: dict[str, Any],
    log: logger.RunLogger,
    milestones: logger.Milestones,
) -> tuple[Any, dict[str, float]]:
    """Host loop: jitted calls of up to updates_per_call updates, logs, checkpoints."""
    done, every = progress["update"], plan.run.checkpoint_every
    per_update = trainer.steps_per_update
    resumed, time_before = plan.checkpoint is not None, progress["time_s"]
    last: dict[str, float] = {}
    show = plan.run.progress and distributed.is_main()
    bar = tqdm(total=trainer.num_updates * per_update, initial=done * per_update, unit="step",
               unit_scale=True, dynamic_ncols=True, disable=not show, file=sys.stderr)  # fmt: skip
    while done < trainer.num_updates and not STOP.requested:
        next_checkpoint = (done // every + 1) * every
        n = min(trainer.updates_per_call, trainer.num_updates - done, next_checkpoint - done)
        start = time.monotonic()
        state, metrics = trainer.run(state, n)
        if trainer.probe is not None:  # the reach probe, apart from run (make_train)
            metrics = {**metrics, "reach_error_mm": trainer.probe(state, n)}
        metrics = jax.device_get(metrics)
        check_finite(state, metrics, done, n)  # a diverged run stops here, nothing saved
        seconds = time.monotonic() - start
        now = elapsed(time_before, resumed)
        rows = logger.rows_from_metrics(metrics, done, per_update, now, n * per_update / seconds)
        done += n
        log.log(rows)
        for message in milestones.update(rows):
            if distributed.is_main():
                bar.write(message)
        last = {k: rows[-1][k] for k in log.columns if k in rows[-1]}
        bar.update(n * per_update)
        bar.set_postfix(
            reward=f"{last['reward_mean']:.3f}",
            dist_mm=f"{last.get('distance_mm', float('nan')):.1f}",
            det_mm=f"{last.get('det_error_mm', float('nan')):.2f}",
            refresh=False,
        )
        if done % every == 0 or done == trainer.num_updates or STOP.requested:
            progress = {
                "update": done,
                "env_steps": done * per_update,
                "time_s": now,
                "milestones": milestones.records,
            }
            path = plan.out / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(done)
            local = distributed.gather(state)  # a collective: every process, then one writes
            if distributed.is_main():
                ckpt.save_checkpoint(path, local, {**meta, "progress": progress})
                runs.prune_checkpoints(plan.out, plan.run.keep_checkpoints)
    bar.close()
    if STOP.requested and done < trainer.num_updates:
        path = plan.out / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(done)
        if not path.exists():  # stopped before the first call: its start is resumable too
            now = elapsed(time_before, resumed)
            progress = {**progress, "update": done, "env_steps": done * per_update, "time_s": now}
            ckpt.save_checkpoint(path, state, {**meta, "progress": progress})
        raise runs.Interrupted
    return state, last


def finish(
    env: Any,
    state: Any,
    plan: Plan,
    meta: dict[str, Any],
    last: dict[str, float],
    milestones: logger.Milestones,
    result: Any = None,
    evaluate_fn: Any = None,
) -> None:
    """Final evaluation (unless `result` is given; `evaluate_fn`: its jitted rollout,
    compiled while training ran), plots and summary.json."""
    if not last and (plan.out / "progress.csv").exists():  # resumed a finished run
        rows = logger.read_csv(plan.out / "progress.csv")
        last = {k: float(v) for k, v in rows[-1].items()} if rows else {}
    metric = (
        "reach_error_mm (the saved policy after probe_reach_steps steps from the reset)"
        if plan.config.curriculum.probe_reach_steps > 0
        else "det_error_mm (one deterministic step from each training env's state)"
    )
    summary: dict[str, Any] = {
        "env_name": plan.env_name,
        "preset": plan.preset,
        "training_last_update": last,
        "training_note": "the last update's row of progress.csv: its rollouts of the sampled "
        "(exploring) policy, e.g. collision_rate is the fraction of those env steps that "
        "collided; `eval` below judges the deployed (deterministic) policy",
        "time_to_accuracy": milestones.records,
        "time_to_accuracy_metric": metric,
        "command_time_s": time.monotonic() - _START,
    }
    if not milestones.records:
        print(f"training's accuracy metric, {metric}, never dropped below 5 mm")
    for name, rec in milestones.records.items():
        print(f"time to {name}: {rec['time_s']:.1f} s ({rec['env_steps']} env steps)")
    if plan.run.evaluate:
        if result is None:
            policy = make_policy(state, plan.config)
            result = evaluate(env, policy, plan.eval, fn=evaluate_fn)
        orientation = is_orient_task(env)
        print(format_table(plan.env_name, result, orientation, plan.eval), flush=True)
        report = {
            **{
                k: meta[k]
                for k in (
                    "env_name",
                    "env_config",
                    "ppo",
                    "policy",
                    "curriculum",
                    "eval",
                    "versions",
                )
            },
            "checkpoint": str(ckpt.list_checkpoints(plan.out)[-1]),
            "episodes": result.episodes(),
            "summary": result.summary(),
            "paper": PAPER_RESULTS.get(plan.env_name),
        }
        runs.write_json(plan.out / "eval.json", report)
        summary["eval"] = report["summary"]
    if plan.run.plots and (plan.out / "progress.csv").exists():
        synchronised = not plan.config.curriculum.stagger_episodes
        reset_every = plan.config.ppo.num_envs * env.max_episode_steps if synchronised else 0
        preset = plan.preset or "(of the checkpoint)"
        title = f"{plan.env_name}, preset {preset}, seed {plan.config.ppo.seed}"
        plots = logger.save_plots(plan.out / "progress.csv", plan.out / "plots", title, reset_every)
        for path in plots:
            print(f"wrote {path}")
    runs.write_json(plan.out / "summary.json", summary)
    print(f"run folder: {plan.out}")


if __name__ == "__main__":
    from mara_mjx.runtime import supervise

    sys.exit(supervise.run(lambda: distributed.run_cli(main, PROG), PROG))
