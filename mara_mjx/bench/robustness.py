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
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import shlex
import sys
import tempfile
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np

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
        "train_args": "--num_envs 4 --num_steps 8 --total_timesteps 64 --num_minibatches 2 "
        "--update_epochs 2 --max_episode_steps 16 --updates_per_call 1",
    }
    POSITIVE: ClassVar[tuple[str, ...]] = (
        "seeds", "episodes", "poses", "draws", "bootstrap", "timeout_s")  # fmt: skip
    SHARES_DEVICE: ClassVar[bool] = True

    def __post_init__(self):
        super().__post_init__()
        check_int("seed_offset", self.seed_offset, minimum=0)
        check_int("eval_seed", self.eval_seed, minimum=0)
        check_int("parallel", self.parallel, minimum=0)
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


def split_recipe(recipe: str) -> tuple[str, str]:
    """(preset, flags) of a recipe string: preset "" for the CLI's choice. ValueError for
    an unknown preset."""
    from mara_mjx.ppo.config import PRESETS

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
    argv += ["--seed", str(config.seed_offset), "--seeds", str(config.seeds)]
    argv += ["--preset", preset] if preset else []
    argv += [*shlex.split(flags), *QUIET, *shlex.split(config.train_args)]
    return argv + ["--out", str(out)]


# ------------------------------------------------------------------ judgements
def load_seeds(run: Path, seeds: list[int]) -> tuple[list[Any], dict[str, Any], list[Any]]:
    """(policies, the first seed's checkpoint meta, each seed's milestones) of a --seeds
    run folder: every seed's newest checkpoint."""
    from mara_mjx.cli import seeds as seeds_cli
    from mara_mjx.ppo import checkpoint as ckpt
    from mara_mjx.ppo.policy import policy_from_checkpoint

    policies, metas = [], []
    for s in seeds:
        arrays, meta = ckpt.load_checkpoint(ckpt.find_checkpoint(seeds_cli.folder(run, s)))
        policies.append(policy_from_checkpoint(arrays, meta))
        metas.append(meta)
    return policies, metas[0], [m["progress"].get("milestones", {}) for m in metas]


def _vmapped(env: Any, eval_config: Any, params: Any, policy: Any, n: int) -> list[Any]:
    """ppo.evaluation's episodes for a seed-stacked policy, one program: EvalResult each."""
    import jax

    from mara_mjx.ppo.evaluation import EvalResult, make_evaluate

    out = jax.device_get(jax.jit(jax.vmap(make_evaluate(env, eval_config, params)))(policy))
    return [EvalResult(**{k: np.asarray(v[i]) for k, v in out.items()}) for i in range(n)]


def judge_fixed(env: Any, policy: Any, n: int, config: RobustnessConfig, orientation: bool):
    """Per seed: the paper's evaluation and the hold (module docstring)."""
    from mara_mjx.ppo.config import EvalConfig

    paper_cfg = EvalConfig(episodes=config.episodes, seed=config.eval_seed)
    hold_cfg = paper_cfg.replace(tolerance_mm=0.0)
    paper = _vmapped(env, paper_cfg, None, policy, n)
    hold = _vmapped(env, hold_cfg, None, policy, n)
    rows = []
    for p, h in zip(paper, hold, strict=True):
        row = {
            "paper": {
                "position_mm": np.mean(p.position_error_mm, 0).tolist(),
                "reached": int(np.sum(p.reached)),
                "episodes": len(p.reached),
                "collisions": int(np.sum(p.collisions)),
            },
            "hold": {
                "position_mm": np.mean(h.position_error_mm, 0).tolist(),
                "worst_episode_mm": np.max(h.position_error_mm, 0).tolist(),
                "collisions_per_episode": float(np.mean(h.collisions)),
                "colliding_episodes": np.flatnonzero(h.collisions).tolist(),
            },
        }
        if orientation:
            row["paper"]["orientation_deg"] = np.mean(p.orientation_error_deg, 0).tolist()
            row["hold"]["orientation_deg"] = np.mean(h.orientation_error_deg, 0).tolist()
        rows.append(row)
    return rows


WORST_EPISODES = 5
"""Worst episodes kept per seed and judgement, to trace a failure without rerunning."""


def pose_summary(result: Any, orientation: bool, poses: Any = None) -> dict[str, Any]:
    """Fractions within 5 and 1 mm (deg), per axis mean / median / p95 / worst
    (target_eval.axis_stats), episodes with a collision, and the WORST_EPISODES worst
    episodes (by the worst axis in mm or deg): index (episode i runs from key i of the
    evaluation seed, so it can be replayed), errors, collisions and, given the `poses`,
    its target."""
    from mara_mjx.ppo.target_eval import axis_stats

    pos = np.asarray(result.position_error_mm, np.float64)
    ok = [pos]
    out: dict[str, Any] = {"position_mm": axis_stats(pos)}
    if orientation:
        ori = np.asarray(result.orientation_error_deg, np.float64)
        ok.append(ori)
        out["orientation_deg"] = axis_stats(ori)
    errors = np.concatenate(ok, 1)
    for t in (5.0, 1.0):
        out[f"within_{t:g}"] = float(np.mean(np.all(errors <= t, axis=1)))
    collisions = np.asarray(result.collisions)
    out["episodes_colliding"] = float(np.mean(collisions > 0))
    worst = []
    for i in np.argsort(-errors.max(1), kind="stable")[:WORST_EPISODES]:
        case = {"episode": int(i), "error": errors[i].round(3).tolist(),
                "collisions": int(collisions[i])}  # fmt: skip
        if poses is not None:
            case.update(target_pos=poses.pos[i].tolist(), target_quat=poses.quat[i].tolist())
        worst.append(case)
    out["worst_episodes"] = worst
    return out


def held_out_params(env: Any, eval_config: Any) -> tuple[Any, Any]:
    """(params, poses) of `eval_config.episodes` episodes, each its own held-out pose of
    the env's region (ppo.target_eval's poses, from `eval_config.seed`)."""
    from mara_mjx.envs import targets
    from mara_mjx.envs.random_target import with_targets

    n, seed = eval_config.episodes, eval_config.seed
    poses = targets.evaluation_poses(env.arm.mj_model, env.region, n, seed)
    params = with_targets(env.make_params(reset_noise=eval_config.noise), poses.pos, poses.quat)
    return params, poses


def judge_targets(env: Any, policy: Any, n: int, config: RobustnessConfig, orientation: bool):
    """Per seed: the held-out poses (ppo.target_eval's poses and episodes)."""
    from mara_mjx.ppo.target_eval import DEFAULTS

    eval_cfg = DEFAULTS.replace(episodes=config.poses, seed=config.eval_seed)
    params, poses = held_out_params(env, eval_cfg)
    return [{"targets": pose_summary(r, orientation, poses)}
            for r in _vmapped(env, eval_cfg, params, policy, n)]  # fmt: skip


def judge_real(meta: dict[str, Any], policy: Any, n: int, config: RobustnessConfig, orientation):
    """Per seed and velocity: the real driver on randomised physics draws."""
    from mara_mjx.envs.random_target import is_random_target
    from mara_mjx.ppo.config import EvalConfig
    from mara_mjx.runtime import runs

    eval_cfg = EvalConfig(
        episodes=config.draws, seed=config.eval_seed, tolerance_mm=0.0, rate_limit=config.rate_limit
    )
    rows: list[dict[str, Any]] = [{"real": {}} for _ in range(n)]
    for v in config.velocities:
        env = runs.make_env(meta, driver="real", velocity=v, randomize=True)
        params, poses = held_out_params(env, eval_cfg) if is_random_target(env) else (None, None)
        for row, r in zip(rows, _vmapped(env, eval_cfg, params, policy, n), strict=True):
            row["real"][f"{v:g}"] = pose_summary(r, orientation, poses)
    return rows


def failure(row: dict[str, Any], task: str, config: RobustnessConfig) -> list[str]:
    """Why a seed fails (module docstring); [] when it does not."""
    from mara_mjx.ppo.evaluation import PAPER_RESULTS

    why = []
    if "paper" in row:
        p = row["paper"]
        if p["reached"] < p["episodes"]:
            why.append(f"reached {p['reached']}/{p['episodes']}")
        paper = PAPER_RESULTS.get(task, {})
        for key, unit in (("position_mm", "mm"), ("orientation_deg", "deg")):
            ref = paper.get(key)
            if ref and key in p:
                over = [f"{a:.2f}>{m:.2f}" for a, (m, _) in zip(p[key], ref, strict=True) if a > m]
                if over:
                    why.append(f"{key.split('_')[0]} over the paper's mean ({unit}): {over}")
    judged = [("targets", row.get("targets"))]
    judged += [(f"real {v} rad/s", r) for v, r in row.get("real", {}).items()]
    for name, r in judged:
        if r is not None and r["within_5"] < config.fail_fraction:
            why.append(f"{name}: {100 * r['within_5']:.1f}% within 5 mm/deg")
    return why


# ------------------------------------------------------------------ statistics
def iqm(x: np.ndarray) -> float:
    """Interquartile mean: the mean of the middle 50% (scipy's trim_mean, 25% each side)."""
    from scipy.stats import trim_mean

    return float(trim_mean(np.asarray(x, np.float64), 0.25))


def iqm_interval(x: np.ndarray, resamples: int, seed: int = 0) -> tuple[float, float]:
    """95% percentile-bootstrap interval of the IQM over seeds (resampled with
    replacement)."""
    from scipy.stats import trim_mean

    x = np.asarray(x, np.float64)
    rng = np.random.default_rng(seed)
    samples = x[rng.integers(0, len(x), size=(resamples, len(x)))]
    stats = trim_mean(samples, 0.25, axis=1)
    return float(np.percentile(stats, 2.5)), float(np.percentile(stats, 97.5))


METRICS: tuple[tuple[str, tuple[str, ...], str, bool], ...] = (
    # (name, path into a seed row, unit, larger is worse)
    ("paper position", ("paper", "position_mm"), "mm", True),
    ("paper orientation", ("paper", "orientation_deg"), "deg", True),
    ("hold position", ("hold", "position_mm"), "mm", True),
    ("hold orientation", ("hold", "orientation_deg"), "deg", True),
    ("hold collisions/episode", ("hold", "collisions_per_episode"), "", True),
    ("poses within 5 mm(/deg)", ("targets", "within_5"), "fraction", False),
    ("poses within 1 mm(/deg)", ("targets", "within_1"), "fraction", False),
    ("poses position mean", ("targets", "position_mm", "mean"), "mm", True),
    ("poses orientation mean", ("targets", "orientation_deg", "mean"), "deg", True),
    ("poses colliding", ("targets", "episodes_colliding"), "fraction", True),
)
REAL_METRICS = (
    ("within 5 mm(/deg)", ("within_5",), "fraction", False),
    ("within 1 mm(/deg)", ("within_1",), "fraction", False),
    ("position mean", ("position_mm", "mean"), "mm", True),
    ("colliding", ("episodes_colliding",), "fraction", True),
)


def metrics_for(rows: list[dict[str, Any]]) -> list[tuple[str, tuple[str, ...], str, bool]]:
    """The metrics present in these seed rows (the real ones per velocity)."""
    out = [m for m in METRICS if _get(rows[0], m[1]) is not None]
    for v in rows[0].get("real", {}):
        out += [(f"real {v} rad/s {n}", ("real", v, *p), u, w) for n, p, u, w in REAL_METRICS]
    return out


def _get(row: Any, path: tuple[str, ...]) -> Any:
    for part in path:
        if not isinstance(row, dict) or part not in row:
            return None
        row = row[part]
    return row


def summarise(rows: list[dict[str, Any]], config: RobustnessConfig) -> list[dict[str, Any]]:
    """One record per metric: per axis (or the scalar) mean, median, IQM and its interval
    over seeds, and the worst seed."""
    records = []
    seeds = [r["seed"] for r in rows]
    for name, path, unit, larger_worse in metrics_for(rows):
        values = np.array([_get(r, path) for r in rows], np.float64)  # (seeds,) or (seeds, 3)
        per_axis = values.reshape(len(rows), -1)
        axes = [iqm_interval(per_axis[:, k], config.bootstrap) for k in range(per_axis.shape[1])]
        score = per_axis.max(1) if larger_worse else -per_axis.min(1)
        worst = int(np.argmax(score))
        records.append({
            "kind": "metric", "task": rows[0]["task"], "recipe": rows[0]["recipe"],
            "metric": name, "unit": unit, "path": ".".join(path), "seeds": len(rows),
            "failed_seeds": [r["seed"] for r in rows if r["failed"]],
            "mean": per_axis.mean(0).tolist(), "median": np.median(per_axis, 0).tolist(),
            "iqm": [iqm(per_axis[:, k]) for k in range(per_axis.shape[1])],
            "iqm_ci95": axes, "worst_seed": seeds[worst], "worst": per_axis[worst].tolist(),
        })  # fmt: skip
    return records


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
    from mara_mjx.ppo.config import default_preset

    jobs = []
    for task in config.tasks:
        for recipe in config.recipes:
            slug = "-".join([task, *(w.strip("-").replace("=", "_") for w in shlex.split(recipe))])
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

    from mara_mjx.envs.random_target import is_random_target
    from mara_mjx.ppo.seed_eval import stack_policies
    from mara_mjx.runtime import runs

    seeds = list(range(config.seed_offset, config.seed_offset + config.seeds))
    base = {"task": job.task, "recipe": job.recipe, "preset": job.preset, "command": job.command}
    if "error" in timing:
        return [{"kind": "error", **base, "error": timing["error"]}]
    try:
        policies, meta, milestones = load_seeds(job.out, seeds)
    except ValueError as e:  # CheckpointError: a run folder the study cannot judge
        return [{"kind": "error", **base, "error": f"cannot load the seeds' checkpoints: {e}"}]
    policy = stack_policies(policies)
    env = runs.make_env(meta)
    orientation = bool(getattr(getattr(env, "task", None), "orientation", False))
    if is_random_target(env):
        rows = judge_targets(env, policy, len(seeds), config, orientation)
    else:
        rows = judge_fixed(env, policy, len(seeds), config, orientation)
    if config.real_driver:
        real = judge_real(meta, policy, len(seeds), config, orientation)
        rows = [{**a, **b} for a, b in zip(rows, real, strict=True)]
    jax.clear_caches()  # the next job's programs differ; free these
    records = []
    for seed, row, marks in zip(seeds, rows, milestones, strict=True):
        why = failure(row, job.task, config)
        records.append({
            "kind": "seed", **base, "seed": seed, **row, "failed": bool(why), "why": why,
            "time_to_1mm_s": marks.get("1mm", {}).get("time_s"),
            "env_steps_to_1mm": marks.get("1mm", {}).get("env_steps"),
        })  # fmt: skip
    trained = {"train_s": timing["command_s"], "train_reused": timing.get("reused", False)}
    summary = [{**r, **base, **trained} for r in summarise(records, config)]
    _print(records, summary)
    return records + summary


def _print(seeds: list[dict], summary: list[dict]) -> None:
    failed = [r for r in seeds if r["failed"]]
    print(f"{seeds[0]['task']} / {seeds[0]['recipe']}: {len(failed)} of {len(seeds)} seeds "
          "failed", flush=True)  # fmt: skip
    for r in failed:
        print(f"    seed {r['seed']}: {'; '.join(r['why'])}")
    for r in summary:
        print(f"  {r['metric']}: mean {_fmt(r['mean'])}, worst seed {r['worst_seed']} "
              f"{_fmt(r['worst'])}", flush=True)  # fmt: skip


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


# ------------------------------------------------------------------ reporting
def _fmt(values: Any, digits: int = 2) -> str:
    values = values if isinstance(values, list) else [values]
    return " / ".join(f"{v:.{digits}f}" if v is not None and math.isfinite(v) else "-"
                      for v in values)  # fmt: skip


def _iqm_cell(r: dict[str, Any]) -> str:
    return " / ".join(
        f"{m:.2f} [{lo:.2f}, {hi:.2f}]" for m, (lo, hi) in zip(r["iqm"], r["iqm_ci95"], strict=True)
    )


def _metric_rows(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in records if r["kind"] == "metric"]


def notes(records: list[dict[str, Any]]) -> list[str]:
    lines = ["Per axis x / y / z (roll / pitch / yaw); IQM with its 95% bootstrap interval "
             "over seeds. Failed seeds and why:", ""]  # fmt: skip
    seeds = [r for r in records if r["kind"] == "seed"]
    for r in seeds:
        if r["failed"]:
            lines.append(f"- {r['task']} / {r['recipe']}, seed {r['seed']}: {'; '.join(r['why'])}")
    if not any(r["failed"] for r in seeds):
        lines.append("- none")
    for r in records:
        if r["kind"] == "error":
            lines.append(f"- {r['task']} / {r['recipe']}: the train command failed: "
                         f"{r['error'].splitlines()[0]}")  # fmt: skip
    commands = {(r["task"], r["recipe"]): r["command"] for r in records}
    lines += ["", "Train commands:", ""]
    lines += [f"- `{c}`" for c in commands.values()]
    return lines


def plot(records: list[dict[str, Any]], title: str, path: Path) -> None:
    """One dot per seed: each recipe's worst axis (position, mm) of its first judgement,
    and the fraction of episodes outside 5 mm where episodes are judged by fraction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seeds = [r for r in records if r["kind"] == "seed"]
    groups = list(dict.fromkeys((r["task"], r["recipe"]) for r in seeds))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(groups) + 2), 4.5))
    for i, (task, recipe) in enumerate(groups):
        rows = [r for r in seeds if (r["task"], r["recipe"]) == (task, recipe)]
        ys = [_headline(r) for r in rows]
        xs = i + np.linspace(-0.25, 0.25, len(rows))
        colours = ["tab:red" if r["failed"] else "tab:blue" for r in rows]
        ax.scatter(xs, np.maximum(ys, 1e-3), c=colours, s=18, zorder=3)
    ax.scatter([], [], c="tab:blue", s=18, label="seed")
    ax.scatter([], [], c="tab:red", s=18, label="failed seed")
    ax.axhline(1.0, color="grey", lw=0.8, ls="--")
    ax.set_xticks(range(len(groups)))
    ax.set_xticklabels([f"{t}\n{r}" for t, r in groups], fontsize=7)
    ax.set_yscale("log")
    from mara_mjx.viz.plots import finish_figure

    finish_figure(fig, ax, path, f"Robustness over seeds ({title})", "task / recipe",
                  "worst axis of the seed's mean error (mm)")  # fmt: skip


def _headline(row: dict[str, Any]) -> float:
    """A seed's worst mean axis error (mm): the paper's evaluation, else the poses."""
    if "paper" in row:
        return max(row["paper"]["position_mm"])
    return max(row["targets"]["position_mm"]["mean"])


STUDY = Study(
    name="robustness",
    config=RobustnessConfig,
    run=robustness_study,
    table={
        "title": "Robustness over seeds: each recipe's seeds, judged as their task is judged",
        "columns": [
            ("task", lambda r: r["task"]),
            ("recipe", lambda r: f"`{r['recipe']}`"),
            ("metric", lambda r: r["metric"] + (f" ({r['unit']})" if r["unit"] else "")),
            ("failed / seeds", lambda r: f"{len(r['failed_seeds'])} / {r['seeds']}"),
            ("mean", lambda r: _fmt(r["mean"])),
            ("median", lambda r: _fmt(r["median"])),
            ("IQM [95% CI]", _iqm_cell),
            ("worst seed", lambda r: f"{r['worst_seed']}: {_fmt(r['worst'])}"),
        ],
        "rows": _metric_rows,
        "notes": notes,
        "plot": plot,
    },
    summary="training recipes over N fresh seeds, each judged as its task is judged",
)
