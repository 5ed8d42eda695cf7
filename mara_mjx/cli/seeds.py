"""Several seeds in one run: `python -m mara_mjx.train --env T --seeds N`.

N independent PPO runs, seeds ppo.seed .. ppo.seed + N - 1, train in one jitted program
(`mara_mjx.ppo.members.make_seed_trainer`: the Trainer vmapped over a leading seed axis,
which is sharded over the devices when there are several; each seed's envs stay on one
device). Seed s computes what `--seed s` alone computes, up to floating-point reduction
order. The run folder:

    <out>/seed_<s>/   one per seed, each exactly what a single run with --seed s writes
                      (config.json with ppo.seed = s and run.seeds = 1, progress.csv, tb/,
                      checkpoints/, eval.json, summary.json, plots/): evaluate, play,
                      export and even --resume work on it alone
    <out>/seeds.json  the seeds; at the end the summary across seeds: per seed the paper's
                      evaluation (mean per axis of the position and orientation errors,
                      episodes within the tolerance, collisions) and the time to 5 mm and
                      1 mm; over the seeds the mean and the worst seed per axis and the
                      median times
    <out>/seeds.md    that summary as a markdown table

Checkpoints of every seed at the same updates; `--resume <out>` continues every seed
from the newest update all of them have a readable checkpoint of. `python -m
mara_mjx.evaluate <out>` evaluates every seed's newest checkpoint (one vmapped program)
and prints and writes the same summary. Not with several processes (jax.distributed) nor
with the envs of one seed over several devices (--devices > 1).

The folder follows `mara_mjx.runtime.runs`' rules: --out must be new, empty or a multi-seed
run's folder; training locks it and every seed's folder; seeds.json is written first, so
a run killed early is still known as one (and started over by the same command). A
seeds.json whose seeds are not distinct ints >= 0 is refused with one line.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from mara_mjx.cli.common import UserError
from mara_mjx.envs.mara import is_orient_task
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo import logger, seed_eval
from mara_mjx.ppo.divergence import check_finite
from mara_mjx.ppo.members import make_seed_trainer, take_seed
from mara_mjx.ppo.policy import make_policy
from mara_mjx.ppo.teacher import teachers_for_seeds
from mara_mjx.runtime import files, outputs, runs, sharding

SEEDS_JSON = "seeds.json"
SEEDS_MD = "seeds.md"


def folder(out: Path, seed: int) -> Path:
    return Path(out) / f"seed_{seed}"


def group_of(path: str | Path | None) -> dict[str, Any] | None:
    """The seeds.json of a multi-seed run folder, or None for anything else;
    CheckpointError if it is unreadable or does not list distinct seeds (ints)."""
    if path is None or not (Path(path) / SEEDS_JSON).is_file():
        return None
    where = str(Path(path) / SEEDS_JSON)
    try:
        group = json.loads((Path(path) / SEEDS_JSON).read_text())
        seeds = group["seeds"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ckpt.CheckpointError(f"{where!r} is unreadable: {e}") from e
    if (
        not isinstance(seeds, list)
        or not seeds
        or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)
        or len(set(seeds)) != len(seeds)
    ):
        raise ckpt.CheckpointError(
            f"{where!r} is damaged: its 'seeds' must list the run's seeds, distinct ints "
            f">= 0 (one seed_<s> folder each), not {seeds!r}"
        )
    return group


# ------------------------------------------------------------------ checks
def check_launch(requested: int, resume: str | None, several_processes: bool) -> None:
    """Before jax.distributed joins: several seeds are one process's."""
    if several_processes and (requested > 1 or group_of(resume) is not None):
        raise UserError(
            "--seeds cannot be combined with several processes (jax.distributed): run the "
            "seeds in one process (they spread over its devices) or one seed per process"
        )


def check(seeds: int, devices: int, available: int) -> None:
    """UserError unless `seeds` seeds fit `devices` (RunConfig.devices) of `available`."""
    if seeds == 1:
        return
    if devices > 1:
        raise UserError(
            f"--devices {devices} spreads one run's envs over devices; with --seeds {seeds} "
            "the seeds are spread over the devices instead (each seed's envs on one "
            "device): use --devices 0 (all devices) or --devices 1 (every seed on one)"
        )
    if devices == 0 and available > 1 and seeds % available:
        raise UserError(
            f"--seeds {seeds} does not divide over the {available} devices; choose a "
            f"multiple of {available} (e.g. {seeds + available - seeds % available}) or "
            "--devices 1 (every seed on one device)"
        )


def find_resume(path: str, given_run: dict[str, Any]) -> tuple[Path, Path | None, dict]:
    """(checkpoint, multi-seed run folder or None, run fields) to resume `path` from: for
    a multi-seed run its first seed's checkpoint of the newest update every seed has."""
    group = group_of(path)
    if group is None:
        if given_run.get("seeds", 1) != 1:
            raise UserError("--seeds cannot change when resuming a run of one seed")
        return ckpt.find_checkpoint(path), None, {}
    seeds = [int(s) for s in group["seeds"]]
    if given_run.get("seeds", len(seeds)) != len(seeds):
        raise UserError(f"--seeds cannot change when resuming a run of {len(seeds)} seeds")
    top = Path(path).resolve()
    names = [{p.name for p in ckpt.list_checkpoints(folder(top, s))} for s in seeds]
    skipped = []
    for name in sorted(set.intersection(*names), reverse=True):  # newest first
        try:
            for s in seeds:
                ckpt.load_checkpoint(folder(top, s) / ckpt.CHECKPOINT_DIR / name)
        except ckpt.CheckpointError as e:
            skipped.append(str(e))
            continue
        if skipped:
            print(f"warning: skipped unreadable checkpoint(s): {'; '.join(skipped)}; using "
                  f"{name} of every seed", file=sys.stderr)  # fmt: skip
        return folder(top, seeds[0]) / ckpt.CHECKPOINT_DIR / name, top, {"seeds": len(seeds)}
    raise ckpt.CheckpointError(
        f"the seeds of {str(path)!r} have no readable checkpoint of a common update "
        f"{skipped or ''}; if the run was stopped before its first checkpoint, start it "
        "again with the same --out"
    )


# --------------------------------------------------------------- training
class Host(NamedTuple):
    """The single-run pieces of the train CLI each seed's folder reuses (passed in, as
    this module may not import the CLI that imports it)."""

    meta: Callable[[Any, Any], dict[str, Any]]
    finish: Callable[..., None]
    stop: runs.StopRequest
    elapsed: Callable[[float, bool], float]
    announce: Callable[[dict[str, Any]], None]
    """The run's header (and its config with --verbose), given the resolved config."""


@dataclasses.dataclass
class Lane:
    """One seed's run folder and host-side state."""

    seed: int
    plan: Any  # mara_mjx.cli.train.Plan of this seed alone
    meta: dict[str, Any]
    progress: dict[str, Any]
    milestones: logger.Milestones
    log: Any = None
    last: dict[str, float] = dataclasses.field(default_factory=dict)


def train(plan: Any, env: Any, trainer: Any, host: Host) -> int:
    """The train CLI for plan.run.seeds > 1 (trainer built with devices=1)."""
    seeds = tuple(range(plan.config.ppo.seed, plan.config.ppo.seed + plan.run.seeds))
    st = make_seed_trainer(trainer, seeds, devices=sharding.device_count(plan.run.devices))
    teachers = None  # imitation: seed s's teacher (a resumed run's are in its checkpoints)
    if trainer.teacher is not None and plan.checkpoint is None:
        try:
            teachers = teachers_for_seeds(plan.config.curriculum.teacher, plan.env_name, seeds)
        except ValueError as e:
            raise UserError(str(e)) from e
    top = plan.out
    locks = [_claim(top)]
    try:
        return _train(plan, env, trainer, host, st, seeds, locks, teachers)
    finally:
        for lock in locks:
            lock.release()


def _claim(top: Path) -> files.FolderLock:
    """Create and lock a multi-seed run's folder: new, empty or a multi-seed run's."""
    if top.is_dir() and not outputs.is_empty(top) and not outputs.is_group_folder(top):
        what = "a run of one seed" if outputs.is_run_folder(top) else "not a mara_mjx run folder"
        raise UserError(
            f"output folder {str(top)!r} exists and is {what}; nothing was changed there. "
            "Choose a new or empty folder for --out"
        )
    lock = runs.claim_folder(top)
    files.remove_temporaries(top, (*outputs.GROUP_FILES, "write-test"))
    return lock


def _train(plan, env, trainer, host: Host, st, seeds, locks: list, teachers=None) -> int:
    """train() in its claimed folder; the seeds' folders' locks are added to `locks`."""
    top = plan.out
    name = None if plan.checkpoint is None else plan.checkpoint.name
    if name is None and any(ckpt.list_checkpoints(folder(top, s)) for s in seeds):
        raise UserError(
            f"output folder {str(top)!r} already holds a run; continue it with --resume "
            f"{top} or choose another --out"
        )
    # first, so that a run killed from here on is known as a multi-seed run's folder
    runs.write_json(top / SEEDS_JSON, {"env_name": plan.env_name, "seeds": list(seeds)})
    lanes = []
    for s in seeds:
        p = dataclasses.replace(
            plan,
            config=plan.config.replace(seed=s),
            run=plan.run.replace(seeds=1, out=str(folder(top, s))),
            out=folder(top, s),
            checkpoint=None if name is None else folder(plan.source_run, s) / "checkpoints" / name,
            source_run=None if name is None else folder(plan.source_run, s).resolve(),
        )
        locks.append(runs.prepare_run_folder(p.out, p.checkpoint, p.source_run))
        progress = {"update": 0, "env_steps": 0, "time_s": 0.0, "milestones": {}}
        if p.checkpoint is not None:
            progress = ckpt.load_checkpoint(p.checkpoint)[1]["progress"]
        lane = Lane(s, p, host.meta(p, env), progress, logger.Milestones(progress["milestones"]))
        lanes.append(lane)
    if len({lane.progress["update"] for lane in lanes}) > 1:
        raise ckpt.CheckpointError(f"the seeds' checkpoints {name} are of different updates")
    state = None
    if plan.checkpoint is not None:
        template = jax.eval_shape(trainer.init, jax.random.key(0))  # traced, not compiled
        states = [
            ckpt.arrays_to_state(ckpt.load_checkpoint(lane.plan.checkpoint)[0], template)
            for lane in lanes
        ]
        state = jax.tree.map(lambda *x: jnp.stack(x), *states)
    for lane in lanes:
        resolved = {**lane.meta, "resume_from": str(lane.plan.checkpoint or "") or None}
        runs.write_json(lane.plan.out / "config.json", resolved)
    resolved = {
        **lanes[0].meta,
        **plan.config.to_dict(),
        "run": plan.run.replace(out=str(top)).to_dict(),
    }
    host.announce({**resolved, "seeds": list(seeds)})

    orientation = is_orient_task(env)
    try:
        with host.stop:  # (on resume the loggers rewrite progress.csv: inside it)
            for lane in lanes:
                lane.log = logger.RunLogger(
                    lane.plan.out,
                    logger.columns(orientation),
                    plan.run.tensorboard,
                    resume_update=lane.progress["update"] if plan.checkpoint else None,
                    resume_env_steps=lane.progress["env_steps"],
                )
            if state is None:
                state = st.init()
                if teachers is not None:  # student seed s learns from teacher seed s
                    state = state.replace(teacher=teachers)
            print(
                f"{plan.env_name}: {len(seeds)} seeds {seeds[0]}..{seeds[-1]} x "
                f"{trainer.num_updates} updates of {plan.config.ppo.num_envs} envs x "
                f"{plan.config.ppo.num_steps} steps, {jax.default_backend()} backend; the first "
                "call compiles",
                flush=True,
            )
            state = _loop(st, state, lanes, plan, host)
    except KeyboardInterrupt:
        if all(ckpt.list_checkpoints(lane.plan.out) for lane in lanes):
            message = f"interrupted; every seed has a checkpoint: --resume {top}"
        else:
            message = (
                "interrupted before every seed had a checkpoint; the same command (same "
                f"--out {top}) starts the run over"
            )
        print(f"\n{message}", file=sys.stderr)
        return runs.exit_status()
    finally:
        for lane in lanes:
            if lane.log is not None:
                lane.log.close()
    try:
        _finish(env, state, lanes, plan, host, orientation)
    except KeyboardInterrupt:
        print(
            "\ninterrupted during the final evaluation; training is complete and every "
            f"seed's last checkpoint whole: --resume {top} runs the evaluation again",
            file=sys.stderr,
        )
        return runs.exit_status()
    return 0


def _loop(st: Any, state: Any, lanes: list[Lane], plan: Any, host: Host) -> Any:
    """Jitted calls of every seed's updates; per seed its CSV rows and checkpoints; one
    progress line (tqdm) for all seeds."""
    trainer, n_seeds = st.trainer, len(lanes)
    done, every = lanes[0].progress["update"], plan.run.checkpoint_every
    per_update = trainer.steps_per_update
    resumed = plan.checkpoint is not None
    bar = tqdm(
        total=trainer.num_updates * per_update * n_seeds,
        initial=done * per_update * n_seeds,
        unit="step",
        unit_scale=True,
        dynamic_ncols=True,
        disable=not plan.run.progress,
        file=sys.stderr,
    )
    while done < trainer.num_updates and not host.stop.requested:
        next_checkpoint = (done // every + 1) * every
        n = min(trainer.updates_per_call, trainer.num_updates - done, next_checkpoint - done)
        start = time.monotonic()
        state, metrics = st.run(state, n)
        metrics = jax.device_get(metrics)
        check_finite(state, metrics, done, n)  # a diverged seed stops all, nothing saved
        rate = n * per_update / (time.monotonic() - start)  # env steps/s of each seed
        for i, lane in enumerate(lanes):
            now = host.elapsed(lane.progress["time_s"], resumed)
            rows = logger.rows_from_metrics(take_seed(metrics, i), done, per_update, now, rate)
            lane.log.log(rows)
            for message in lane.milestones.update(rows):
                bar.write(f"seed {lane.seed}: {message}")
            lane.last = {k: rows[-1][k] for k in lane.log.columns if k in rows[-1]}
        done += n
        det = np.array([lane.last.get("det_error_mm", np.nan) for lane in lanes])
        bar.update(n * per_update * n_seeds)
        bar.set_postfix(
            reward=f"{np.mean([lane.last['reward_mean'] for lane in lanes]):.3f}",
            det_mm_median=f"{np.nanmedian(det) if np.isfinite(det).any() else np.nan:.2f}",
            worst=f"{np.nanmax(det) if np.isfinite(det).any() else np.nan:.2f}",
            refresh=False,
        )
        if done % every == 0 or done == trainer.num_updates or host.stop.requested:
            _save(state, lanes, done, per_update, host, resumed)
    bar.close()
    if host.stop.requested and done < trainer.num_updates:
        path = lanes[0].plan.out / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(done)
        if not path.exists():  # stopped before the first call: its start is resumable too
            _save(state, lanes, done, per_update, host, resumed)
        raise runs.Interrupted
    return state


def _save(state: Any, lanes: list[Lane], done: int, per_update: int, host: Host, resumed):
    for i, lane in enumerate(lanes):
        progress = {
            "update": done,
            "env_steps": done * per_update,
            "time_s": host.elapsed(lane.progress["time_s"], resumed),
            "milestones": lane.milestones.records,
        }
        path = lane.plan.out / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(done)
        ckpt.save_checkpoint(path, take_seed(state, i), {**lane.meta, "progress": progress})
        runs.prune_checkpoints(lane.plan.out, lane.plan.run.keep_checkpoints)


def _finish(env, state, lanes: list[Lane], plan, host: Host, orientation: bool) -> None:
    """Every seed's finish (its eval.json, summary.json, plots; output kept in its files),
    the evaluation of all seeds in one vmapped program, then the summary across seeds."""
    results = None
    if plan.run.evaluate:
        results = seed_eval.evaluate_seeds(
            env, make_policy(state, plan.config), plan.eval, len(lanes)
        )
    rows = []
    for i, lane in enumerate(lanes):
        result = None if results is None else results[i]
        with contextlib.redirect_stdout(io.StringIO()):
            host.finish(env, take_seed(state, i), lane.plan, lane.meta, lane.last,
                        lane.milestones, result=result)  # fmt: skip
        rows.append(seed_eval.seed_row(lane.seed, result, lane.milestones.records))
    report = seed_eval.summarise(plan.env_name, orientation, rows, plan.eval.to_dict())
    write_summary(plan.out, report)
    print(seed_eval.markdown(report))
    print(f"run folder: {plan.out} (one folder per seed: seed_<s>/)")


def write_summary(out: Path, report: dict[str, Any], stem: str = "seeds") -> None:
    runs.write_json(Path(out) / f"{stem}.json", report)
    files.write_atomic(Path(out) / f"{stem}.md", seed_eval.markdown(report) + "\n")
