"""The `robustness` study of `python -m mara_mjx.benchmark`: does a training recipe work on
seeds nobody tuned on?

    python -m mara_mjx.benchmark robustness --tasks MARA MARAOrient --recipes cli default
    python -m mara_mjx.benchmark robustness --tasks MARACollision \\
        --recipes "default --randomize" --real_driver --seed_offset 1000 --seeds 16

For each task of `--tasks` and each recipe of `--recipes`, `--seeds` (16) seeds from
`--seed_offset` (1000) train in one vmapped program: the user's own command, as a fresh
process,

    python -m mara_mjx.train --env TASK --seed OFFSET --seeds N [--preset P] [FLAGS]
        --evaluate false --plots false --tensorboard false --progress false --out RUN

A recipe is a preset name and train flags in one string: "cli" stands for the train CLI's
own choice for the task (no --preset: what `python -m mara_mjx.train --env TASK` trains),
"default --population 4" for `--preset default --population 4`. Then every seed's final
checkpoint is judged the way its task is judged, all seeds in one vmapped program per
judgement, with evaluation keys and poses from `--eval_seed` (1000, not the CLI's 0):

paper    fixed-target tasks: the paper's evaluation (`--episodes` episodes, each stopping
         at 5 mm on every axis or at the horizon): per axis the mean final error (mm; deg
         on the Orient tasks), episodes reached, collisions.
hold     fixed-target tasks: the same episodes run to the horizon (no stop): where the
         policy holds the arm, and collisions per episode on the way.
targets  random-target tasks: `--poses` (1,000) held-out poses (`ppo.target_eval`), each
         episode to the horizon: fractions within 5 mm (and 5 deg) and 1 mm (and 1 deg),
         per axis mean, p95 and worst, episodes with a collision.
real     with `--real_driver`: the real driver (servos at each of `--velocities` rad/s)
         with randomised physics (`RandomizeConfig` defaults: masses, friction, gains,
         zero offsets, sensor noise, latency), `--draws` (1,000) episodes each its own draw
         (and, on a random-target task, its own held-out pose), to the horizon: fractions
         within 5 mm and 1 mm (and deg), per axis mean, p95 and worst, episodes with a
         collision or a physics blow-up.

A seed fails when it misses the task's bar: paper: not every episode reached, or a mean
axis error above the paper's mean for that axis; targets and real: fewer than
`--fail_fraction` (99%) of the episodes within 5 mm (and 5 deg) at the horizon. Per
recipe and metric the study reports the mean, the median, the interquartile mean (IQM:
the mean of the middle 50% of seeds) with a 95% percentile-bootstrap interval over
seeds (`--bootstrap` resamples, as rliable reports RL results), and the worst seed with
all its numbers. Output: robustness.json (every seed's numbers, the commands),
robustness.md (one row per recipe and metric, failures named) and robustness.png (one
dot per seed, failed seeds in red).

`--select K` judges a recipe that trains K seeds and keeps the one that transfers: seeds x
K seeds train in the one program, each seed is first run on the real driver with
randomised physics (`--select_draws` draws per velocity, keys from `--select_seed`, not
the judged ones) and, on a random-target task, on `--poses` poses of the train driver
drawn from `--select_seed` too (not the held-out ones judged), and of each group of K
consecutive seeds only the best (`robustness_judge.selection_score`: the highest smallest
fraction within 5 mm over the velocities and within 1 mm of the train driver's poses,
then the smallest largest fraction of episodes with a collision, then the lowest mean
error) is judged as above; its record names the group and every candidate's selection
numbers.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shlex
import sys
import tempfile
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

from mara_mjx.bench.robustness_judge import (
    failure,
    judge_fixed,
    judge_real,
    judge_targets,
    load_seeds,
    select_seeds,
)
from mara_mjx.bench.robustness_report import TABLE, print_job, summarise
from mara_mjx.bench.runner import BenchConfig, Study
from mara_mjx.bench.train_command import QUIET, check_train_args, child_env, launch
from mara_mjx.config import check_int

CLI = "cli"
"""The recipe name standing for the train CLI's own choice of preset for the task."""
TRAIN_FLAGS_SET_BY_STUDY = ("--seeds", "--run.seeds")


@dataclasses.dataclass(frozen=True)
class RobustnessConfig(BenchConfig):
    """The robustness study's settings."""

    recipes: tuple[str, ...] = (CLI,)
    """Recipes: a preset name (or "cli": the train CLI's choice for the task) followed by
    train flags, one string each, e.g. "default --population 4"."""
    seeds: int = 16
    """Training seeds per task and recipe, trained in one vmapped program."""
    seed_offset: int = 1000
    """First training seed (seeds seed_offset .. seed_offset + seeds - 1)."""
    eval_seed: int = 1000
    """Seed of every evaluation's episodes (reset noise, held-out poses, physics draws)."""
    episodes: int = 10
    """Episodes of the paper's evaluation and of the hold (fixed-target tasks)."""
    poses: int = 1000
    """Held-out target poses (random-target tasks)."""
    real_driver: bool = False
    """Also judge every seed on the real driver with randomised physics."""
    velocities: tuple[float, ...] = (0.3, 0.5)
    """Servo speeds (rad/s) of the real-driver judgement."""
    draws: int = 1000
    """Episodes (physics draws) of the real-driver judgement, per velocity."""
    rate_limit: bool = False
    """Real-driver judgement: the policy's steps limited to the servos' travel per step
    (EvalConfig.rate_limit)."""
    collision_guard_mm: float = -1.0
    """Every judgement: the deployed policy's collision guard (EvalConfig.collision_guard_mm;
    -1: as each checkpoint was trained; >= 0 replaces it, 0: off)."""
    plan_steps: int = -1
    """Every judgement: the deployed policy's imagined train-driver steps
    (EvalConfig.plan_steps; -1: as each checkpoint was trained; >= 0 replaces it, 0: off)."""
    plan_starts: int = -1
    """Every judgement: the deployed plan's other starting postures (EvalConfig.plan_starts;
    -1: as each checkpoint was trained; >= 0 replaces it, 0: off)."""
    commit_rad: float = -1.0
    """Every judgement: the deployed policy's held commands' arrival tolerance
    (EvalConfig.commit_rad; -1: as each checkpoint was trained; >= 0 replaces it, 0: off)."""
    fail_fraction: float = 0.99
    """targets and real: a seed fails below this fraction of episodes within 5 mm (5 deg)."""
    bootstrap: int = 2000
    """Bootstrap resamples of the IQM's 95% interval."""
    train_args: str = ""
    """More flags for every train command (one string), after the recipe's own."""
    timeout_s: int = 3600
    """Limit on each train command (seconds)."""
    parallel: int = 0
    """Train commands at a time, each on its own GPU (0: one per GPU of the host; 1 or a
    host without several GPUs: one at a time)."""
    select: int = 1
    """Seeds trained per judged seed (K): each group of K keeps its seed that does best on
    the real driver with randomised physics (the module docstring). 1: no selection."""
    select_draws: int = 200
    """Episodes (physics draws) per velocity of the selection run."""
    select_seed: int = -1
    """Seed of the selection run's draws (-1: eval_seed + 1; never eval_seed)."""
    work_dir: str = ""
    """Folder that receives the run folders and command logs, and is kept: a rerun with
    the same folder judges the runs whose same train command finished there instead of
    training them again ("": a temporary folder, deleted at the end)."""

    QUICK: ClassVar[dict[str, Any]] = {
        "tasks": ("MARA",),
        "seeds": 2,
        "episodes": 2,
        "poses": 4,
        "draws": 4,
        "bootstrap": 50,
        "select_draws": 4,
        "train_args": "--num_envs 4 --num_steps 8 --total_timesteps 64 --num_minibatches 2 "
        "--update_epochs 2 --max_episode_steps 16 --updates_per_call 1",
    }
    POSITIVE: ClassVar[tuple[str, ...]] = (
        "seeds", "episodes", "poses", "draws", "bootstrap", "timeout_s", "select",
        "select_draws")  # fmt: skip
    SHARES_DEVICE: ClassVar[bool] = True

    def __post_init__(self):
        super().__post_init__()
        check_int("seed_offset", self.seed_offset, minimum=0)
        check_int("eval_seed", self.eval_seed, minimum=0)
        check_int("parallel", self.parallel, minimum=0)
        check_int("select_seed", self.select_seed, minimum=-1)
        from mara_mjx.ppo.parametrisation import check_overrides

        check_overrides(self.plan_steps, self.plan_starts, self.commit_rad)
        if self.selection_seed == self.eval_seed:
            raise ValueError(
                f"select_seed={self.select_seed} is eval_seed: the seeds would be chosen on "
                "the episodes they are judged on; choose another"
            )
        if not self.recipes or len(set(self.recipes)) != len(self.recipes):
            raise ValueError(f"recipes must be distinct and at least one, got {self.recipes}")
        if not 0.0 < self.fail_fraction <= 1.0:
            raise ValueError(f"fail_fraction must be in (0, 1], got {self.fail_fraction}")
        if not self.velocities or any(not 0.0 < v <= 10.0 for v in self.velocities):
            raise ValueError(f"velocities must be in (0, 10] rad/s, got {self.velocities}")
        for task in self.tasks:
            for recipe in self.recipes:
                preset, flags = split_recipe(recipe)
                taken = [
                    a for a in shlex.split(flags) if a.split("=")[0] in TRAIN_FLAGS_SET_BY_STUDY
                ]
                if taken:
                    raise ValueError(f"recipe {recipe!r}: the study sets {' '.join(taken)}")
                check_train_args(f"{flags} {self.train_args}", task, preset)

    @property
    def selection_seed(self) -> int:
        """The selection run's seed (select_seed, or eval_seed + 1)."""
        return self.eval_seed + 1 if self.select_seed < 0 else self.select_seed


def split_recipe(recipe: str) -> tuple[str, str]:
    """(preset, flags) of a recipe string: preset "" for the CLI's choice. ValueError for
    an unknown preset."""
    from mara_mjx.ppo.presets import PRESETS

    words = shlex.split(recipe)
    if not words:
        raise ValueError("a recipe is a preset name or 'cli', then flags; got ''")
    name, flags = words[0], shlex.join(words[1:])
    if name == CLI:
        return "", flags
    if name not in PRESETS:
        raise ValueError(f"recipe {recipe!r}: unknown preset {name!r}; choose 'cli' or one of "
                         f"{sorted(PRESETS)}")  # fmt: skip
    return name, flags


def train_argv(config: RobustnessConfig, task: str, recipe: str, out: Path) -> list[str]:
    """The train command of the module docstring."""
    preset, flags = split_recipe(recipe)
    argv = [sys.executable, "-m", "mara_mjx.train", "--env", task]
    argv += ["--seed", str(config.seed_offset), "--seeds", str(config.seeds * config.select)]
    argv += ["--preset", preset] if preset else []
    argv += [*shlex.split(flags), *QUIET, *shlex.split(config.train_args)]
    return argv + ["--out", str(out)]


# ------------------------------------------------------------------ the study
class Job(NamedTuple):
    """One train command of the study: a task and a recipe's seeds."""

    task: str
    recipe: str
    preset: str  # the preset it trains (the CLI's choice resolved)
    out: Path  # its run folder
    log: Path  # its output
    argv: tuple[str, ...]

    @property
    def command(self) -> str:
        return "python " + shlex.join(self.argv[1:])


def make_jobs(config: RobustnessConfig, work: Path) -> list[Job]:
    from mara_mjx.ppo.presets import default_preset

    jobs = []
    for task in config.tasks:
        for recipe in config.recipes:
            words = (w.strip("-").replace("=", "_").replace("/", "_") for w in shlex.split(recipe))
            slug = "-".join([task, *words])[:120]  # (a --teacher path: one folder, not nested)
            # the command (but its --out) in the name: a rerun with other flags or seeds in
            # the same work folder gets its own run folder, never another command's run
            command = shlex.join(train_argv(config, task, recipe, Path("RUN"))[1:-2])
            slug += "-" + hashlib.sha256(command.encode()).hexdigest()[:8]
            out = work / "runs" / slug
            preset = split_recipe(recipe)[0] or default_preset(task)
            argv = tuple(train_argv(config, task, recipe, out))
            jobs.append(Job(task, recipe, preset, out, work / f"{slug}.log", argv))
    return jobs


def gpu_slots(parallel: int, visible: str | None = None) -> list[str | None]:
    """CUDA_VISIBLE_DEVICES of each concurrent train command: one per GPU this process
    sees (`parallel` 0: all; N: the first N), named as the user's CUDA_VISIBLE_DEVICES
    (`visible`, default this process's) names them, since JAX numbers the visible GPUs
    from 0; or [None] (one at a time, the user's setting) without several GPUs."""
    import os

    import jax

    count = sum(d.platform == "gpu" for d in jax.devices())
    if count < 2 or parallel == 1:
        return [None]
    visible = os.environ.get("CUDA_VISIBLE_DEVICES") if visible is None else visible
    names = [v.strip() for v in visible.split(",")] if visible else [str(i) for i in range(count)]
    return names[: min(parallel or count, count)]


def continue_argv(config: RobustnessConfig, job: Job) -> list[str]:
    """The job's command; for a run folder an earlier, unfinished study left with
    checkpoints: `--resume` of it (bitwise the run's own continuation); a folder it left
    without any checkpoint is the study's own and holds nothing: removed."""
    import shutil

    from mara_mjx.cli import seeds as seeds_cli
    from mara_mjx.ppo import checkpoint as ckpt

    if not job.out.exists():
        return list(job.argv)
    if ckpt.list_checkpoints(seeds_cli.folder(job.out, config.seed_offset)):
        print(f"continuing the unfinished run {job.out}", flush=True)
        return [*job.argv[:3], "--resume", str(job.out), *QUIET]
    shutil.rmtree(job.out)
    return list(job.argv)


def train_all(config: RobustnessConfig, jobs: list[Job]) -> list[dict[str, Any]]:
    """Run every job's train command, as many at a time as there are GPU slots (each on
    its own GPU); per job its timing, or {"error": ...} if the command failed. A job whose
    same command already finished in the work folder (a rerun with --work_dir) is not
    trained again."""
    import queue
    from concurrent.futures import ThreadPoolExecutor

    slots: queue.Queue[str | None] = queue.Queue()
    for slot in gpu_slots(config.parallel):
        slots.put(slot)

    def train(job: Job) -> dict[str, Any]:
        done = job.log.with_suffix(".done")  # the command and its timing, once it succeeded
        if done.is_file() and json.loads(done.read_text()).get("command") == job.command:
            print(f"reusing the finished run of {job.command}", flush=True)
            return {**json.loads(done.read_text())["timing"], "reused": True}
        argv = continue_argv(config, job)
        slot = slots.get()
        env = child_env()
        if slot is not None:
            env["CUDA_VISIBLE_DEVICES"] = slot
        print(f"training {job.task} / {job.recipe} (GPU {slot or 'default'}): {job.command}",
              flush=True)  # fmt: skip
        try:
            timing = launch(argv, env, job.log, config.timeout_s)
            done.write_text(json.dumps({"command": job.command, "timing": timing}))
            print(f"  trained {job.task} / {job.recipe} in {timing['command_s']:.0f} s", flush=True)
            return timing
        except RuntimeError as e:
            print(f"  FAILED {job.task} / {job.recipe}: {e}", flush=True)
            return {"error": str(e)[-2000:]}
        finally:
            slots.put(slot)

    with ThreadPoolExecutor(max_workers=slots.qsize()) as pool:
        return list(pool.map(train, jobs))


def judge(config: RobustnessConfig, job: Job, timing: dict[str, Any]) -> list[dict[str, Any]]:
    """Judge one trained job's seeds: the seed records and the metric records."""
    import jax

    from mara_mjx.envs.mara import is_orient_task
    from mara_mjx.envs.random_target import is_random_target
    from mara_mjx.ppo.seed_eval import stack_policies
    from mara_mjx.runtime import runs

    seeds = list(range(config.seed_offset, config.seed_offset + config.seeds * config.select))
    base = {"task": job.task, "recipe": job.recipe, "preset": job.preset, "command": job.command}
    if "error" in timing:
        return [{"kind": "error", **base, "error": timing["error"]}]
    try:
        policies, meta, milestones = load_seeds(job.out, seeds)
    except ValueError as e:  # CheckpointError: a run folder the study cannot judge
        return [{"kind": "error", **base, "error": f"cannot load the seeds' checkpoints: {e}"}]
    env = runs.make_env(meta)
    orientation = is_orient_task(env)
    chosen = [{}] * len(seeds)  # no selection: no record
    if config.select > 1:  # the module docstring's --select; its own seed, and no
        # select_seed to check against it
        trial = dataclasses.replace(
            config, draws=config.select_draws, eval_seed=config.selection_seed, select_seed=-1
        )
        stacked = stack_policies(policies)
        tried = judge_real(meta, stacked, len(seeds), trial, orientation)
        if is_random_target(env):  # and the train driver on the selection's own poses
            on_train = judge_targets(env, stacked, len(seeds), trial, orientation)
            tried = [{**a, **b} for a, b in zip(on_train, tried, strict=True)]
        picks, chosen = select_seeds(seeds, tried, config.select)
        seeds = [seeds[i] for i in picks]
        policies, milestones = [policies[i] for i in picks], [milestones[i] for i in picks]
    policy = stack_policies(policies)
    if is_random_target(env):
        rows = judge_targets(env, policy, len(seeds), config, orientation)
    else:
        rows = judge_fixed(env, policy, len(seeds), config, orientation)
    if config.real_driver:
        real = judge_real(meta, policy, len(seeds), config, orientation)
        rows = [{**a, **b} for a, b in zip(rows, real, strict=True)]
    jax.clear_caches()  # the next job's programs differ; free these
    records = []
    for seed, row, marks, pick in zip(seeds, rows, milestones, chosen, strict=True):
        why = failure(row, job.task, config)
        records.append({
            "kind": "seed", **base, "seed": seed, **row, "failed": bool(why), "why": why,
            **({"selection": pick} if pick else {}),
            "time_to_1mm_s": marks.get("1mm", {}).get("time_s"),
            "env_steps_to_1mm": marks.get("1mm", {}).get("env_steps"),
        })  # fmt: skip
    trained = {"train_s": timing["command_s"], "train_reused": timing.get("reused", False)}
    summary = [{**r, **base, **trained} for r in summarise(records, config)]
    print_job(records, summary)
    return records + summary


def robustness_study(config: RobustnessConfig) -> list[dict[str, Any]]:
    if config.work_dir:
        work = Path(config.work_dir)
        work.mkdir(parents=True, exist_ok=True)
        return _run_all(config, work)
    with tempfile.TemporaryDirectory(prefix="mara-robustness-") as tmp:
        return _run_all(config, Path(tmp))


def _run_all(config: RobustnessConfig, work: Path) -> list[dict[str, Any]]:
    jobs = make_jobs(config, work)
    timings = train_all(config, jobs)
    return [r for job, t in zip(jobs, timings, strict=True) for r in judge(config, job, t)]


STUDY = Study(
    name="robustness",
    config=RobustnessConfig,
    run=robustness_study,
    table=TABLE,
    summary="training recipes over N fresh seeds, each judged as its task is judged",
)
