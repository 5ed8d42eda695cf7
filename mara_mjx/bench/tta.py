"""The `tta` study of `python -m mara_mjx.benchmark`: time to accuracy from command start,
as a user of the train CLI sees it, with the PPO's speed under XLA's GPU-op choices and
the env step against the device's ceilings (issue 14).

On the one task of `--tasks` (default MARACollisionOrient), five parts (`--parts`):

tta      For each of `--seeds`, the user's command, as a fresh subprocess:
             python -m mara_mjx.train --env TASK --seed S [--preset P] --evaluate false
                 --plots false --tensorboard false --progress false [--train_args ...]
                 --out RUN --compilation_cache CACHE
         twice: `cold`, CACHE a new, empty folder, then `warm`, the same folder (holding
         the cold run's programs). XLA_FLAGS as the user gave them, so the CLI makes its
         own choice (for the train driver `--xla_gpu_autotune_level=0`: README,
         "Reproducible GPU runs"). Read from the run folder: the time to 5 mm and 1 mm
         (summary.json's `time_to_accuracy`: the CLI's first progress row with
         `det_error_mm` below each; granularity one jitted call), when the first jitted
         call (compile included) was done, env steps/s (the median of progress.csv's
         `steps_per_s` over the rows after the first call: each call's env steps over
         its seconds, so compile and the host logging between calls are excluded), the
         final `det_error_mm` and a hash of every array of the final checkpoint (its JSON
         metadata, which holds paths and times, left out): `same_bits_as_cold` on a warm
         run says whether the cache changed the result. Per phase, the median over
         seeds (kind "median"); a seed that never reached a threshold counts as later
         than any that did, and a median that falls on such a seed is None.
xla_ops  For the first seed, the same command (no persistent cache: `--compilation_cache
         false`; `--xla_ops_total_timesteps` env steps) with `--xla_gpu_deterministic_ops
         =true` and `=false` appended to XLA_FLAGS (an earlier setting of that flag
         dropped; naming it stops the CLI from adding its own): env steps/s of the PPO
         with XLA's deterministic GPU ops and with XLA's defaults. The tta runs give the
         CLI's default, the third choice. The flag is a GPU flag: a CPU parses and ignores
         it, so there the two runs differ only by noise.
seeds    For each of `--seed_counts` N, the same command with `--seeds N` (seeds S .. S + N -
         1 from the first of `--seeds`, one vmapped program: the way to fill a GPU;
         `--seeds_total_timesteps` env steps per seed), cold and warm as in tta: the PPO's
         env steps/s over all N seeds (the sum of every seed's median `steps_per_s`), the
         median over the seeds of the times to 5 mm and 1 mm, and whether every seed's
         final state is bitwise its cold run's (`same_bits_as_cold`).
limit    `mara_mjx.bench.limit.limit_study` (the limit study itself) for the train driver
         of the task at `--limit_num_envs` environments: XLA's FLOPs and bytes of one env
         step against the float32 matmul FLOP/s and memory bandwidth measured in the same
         run, the roofline bound on env steps/s and the env step's measured rate. Also
         the PPO's warm median env steps/s (tta part) as a fraction of that bound (the PPO
         does more than step the envs: how far training is from the env step's ceiling).
         It runs in this process after the trainings, which had the device to
         themselves: this process keeps JAX's GPU memory preallocation off
         (`BenchConfig.SHARES_DEVICE`), and the study's `--deterministic` flag acts on
         this part alone (the train commands get the user's XLA_FLAGS, as above).
peers    The alternatives on the same machine, after the rest: C MuJoCo doing the train
         driver's work (kinematics + collision) on every CPU core at `--limit_num_envs`
         environments (the `peers` study's train-driver side), against the limit part's
         MJX rate at that size; then brax's PPO against ours (the `brax` study: its
         `default` preset, `--peers_total_timesteps` env steps each, both scored alike
         by the same settled-error probe), their env steps/s and time to 5 mm and 1 mm
         from the start of training.

Clocks ("from command start", `launch_offset_s`, `command_s`, the CLI's times moved onto
the launch clock): `mara_mjx.bench.train_command`, which launches and reads every train
command.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import shlex
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any, ClassVar, Literal

from mara_mjx.bench.runner import BenchConfig, Study
from mara_mjx.bench.train_command import (
    QUIET,
    THRESHOLDS_MM,
    check_train_args,
    child_env,
    launch,
    read_run,
)
from mara_mjx.bench.tta_report import CLI_DEFAULT, TTA_TABLE, mega, secs
from mara_mjx.config import check_int

XLA_OPS = {"deterministic": "true", "non-deterministic": "false"}


@dataclasses.dataclass(frozen=True)
class TTAConfig(BenchConfig):
    """The tta study's settings."""

    tasks: tuple[str, ...] = ("MARACollisionOrient",)
    """The registered env to train (one)."""
    parts: tuple[Literal["tta", "xla_ops", "seeds", "limit", "peers"], ...] = (
        "tta",
        "xla_ops",
        "seeds",
        "limit",
        "peers",
    )
    """Parts to run (module docstring)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Seeds of the tta part, each trained cold and warm; xla_ops uses the first."""
    preset: str = ""
    """The train CLI's --preset ("": the CLI's default for the task)."""
    train_args: str = ""
    """More flags for every train command (one string, shell quoting), e.g.
    "--num_envs 4096 --learning_rate 1e-3" (a single flag alone: --train_args='--flag');
    they come after the study's --evaluate false ... and so override them. Note that
    --total_timesteps also stretches the learning-rate schedule and the curricula, so
    it changes the time to accuracy."""
    xla_ops_total_timesteps: int = 10_000_000
    """--total_timesteps of the xla_ops runs (0: as the tta runs)."""
    seed_counts: tuple[int, ...] = (16,)
    """Seed counts N of the seeds part (each `--seeds N`, cold and warm)."""
    seeds_total_timesteps: int = 10_000_000
    """--total_timesteps of the seeds part's runs, per seed (0: as the tta runs)."""
    limit_num_envs: int = 2048
    """Environments of the limit part's env step (2048: the default preset's) and of the
    peers part's C MuJoCo."""
    peers_total_timesteps: int = 10_000_000
    """Env steps of each PPO (brax's and ours) in the peers part (0: the brax study's
    default, or its --quick size)."""
    timeout_s: int = 1200
    """Limit on each train command (seconds)."""
    work_dir: str = ""
    """Where a new folder receives the run folders, compilation caches and command logs,
    and is kept ("": a temporary folder, deleted at the end)."""

    QUICK: ClassVar[dict[str, Any]] = {
        "seeds": (0,),
        "train_args": "--num_envs 4 --num_steps 8 --total_timesteps 64 --num_minibatches 2 "
        "--update_epochs 2 --max_episode_steps 16 --updates_per_call 1",
        "xla_ops_total_timesteps": 0,
        "seed_counts": (2,),
        "seeds_total_timesteps": 0,
        "limit_num_envs": 4,
        "peers_total_timesteps": 0,
    }
    POSITIVE: ClassVar[tuple[str, ...]] = ("limit_num_envs", "timeout_s", "seed_counts")
    SHARES_DEVICE: ClassVar[bool] = True

    def __post_init__(self):
        super().__post_init__()
        from mara_mjx.ppo.presets import PRESETS

        if len(self.tasks) != 1:
            raise ValueError(f"tta trains one task; got --tasks {' '.join(self.tasks)}")
        if not self.parts:
            raise ValueError("parts: give at least one of tta, xla_ops, seeds, limit, peers")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds must be distinct and at least one, got {self.seeds}")
        for seed in self.seeds:
            check_int("seeds", seed, minimum=0)
        check_int("xla_ops_total_timesteps", self.xla_ops_total_timesteps, minimum=0)
        check_int("seeds_total_timesteps", self.seeds_total_timesteps, minimum=0)
        check_int("peers_total_timesteps", self.peers_total_timesteps, minimum=0)
        if len(set(self.seed_counts)) != len(self.seed_counts) or (
            "seeds" in self.parts and not self.seed_counts
        ):
            raise ValueError(
                f"seed_counts must be distinct and at least one, got {self.seed_counts}"
            )
        if self.preset and self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; choose one of {sorted(PRESETS)}")
        check_train_args(self.train_args, self.tasks[0], self.preset)


def train_argv(
    config: TTAConfig, seed: int, out: Path, cache: str, total: int = 0, seeds: int = 1
) -> list[str]:
    """The train command of the module docstring (`total` > 0: --total_timesteps last;
    `seeds` > 1: --seeds)."""
    argv = [sys.executable, "-m", "mara_mjx.train", "--env", config.tasks[0], "--seed", str(seed)]
    argv += ["--seeds", str(seeds)] if seeds > 1 else []
    argv += ["--preset", config.preset] if config.preset else []
    argv += [*QUIET, *shlex.split(config.train_args)]
    argv += ["--total_timesteps", str(total)] if total else []
    return argv + ["--out", str(out), "--compilation_cache", cache]


def run_train(
    config: TTAConfig, work: Path, name: str, argv_args: dict[str, Any], xla_ops: str | None
) -> dict[str, Any]:
    """One train command, its record."""
    out = work / "runs" / name
    argv = train_argv(config, out=out, **argv_args)
    env = child_env(xla_ops)
    timing = launch(argv, env, work / f"{name}.log", config.timeout_s)
    prefix = f"XLA_FLAGS={shlex.quote(env['XLA_FLAGS'])} " if xla_ops is not None else ""
    n = argv_args.get("seeds", 1)
    offset = timing["launch_offset_s"]
    return {
        "kind": "run",
        "task": config.tasks[0],
        "seed": argv_args["seed"],
        "command": prefix + "python " + shlex.join(argv[1:]),
        "xla_flags_given": env.get("XLA_FLAGS", ""),
        **timing,
        "num_seeds": n,
        **(read_run(out, offset) if n == 1 else read_seeds(out, argv_args["seed"], n, offset)),
    }


def read_seeds(out: Path, first: int, n: int, offset: float | None) -> dict[str, Any]:
    """A `--seeds n` run folder as one record: `read_run` of every seed's folder, env
    steps/s summed (one program trains them all), the times to accuracy and the final
    errors as medians over the seeds, the first call when the last seed's was done, the
    hashes over every seed's (in seed order); `per_seed` keeps each seed's record (the
    times: the median's seed that never reached a threshold counts as later than any)."""
    per = [read_run(out / f"seed_{s}", offset) for s in range(first, first + n)]
    rec = threshold_medians(per)
    for mm in THRESHOLDS_MM:  # whole env steps (a median of an even count is a mean of two)
        key = f"to_{mm:g}mm_env_steps"
        rec[key] = None if rec[key] is None else round(rec[key])
    rates = [r["env_steps_per_s"] for r in per]
    for key in ("state_hash", "training_hash"):
        hashes = [r[key] for r in per]
        joined = None if None in hashes else "".join(hashes)
        rec[key] = hashlib.sha256(joined.encode()).hexdigest()[:16] if joined else None
    return {
        **rec,
        "num_seeds": n,
        "env_steps": sum(r["env_steps"] for r in per),
        "first_call_s": max(r["first_call_s"] for r in per),
        "env_steps_per_s": None if None in rates else sum(rates),
        "final_det_error_mm": statistics.median(r["final_det_error_mm"] for r in per),
        "cli_command_time_s": max(r["cli_command_time_s"] for r in per),
        "per_seed": per,
    }


# ------------------------------------------------------------------------ parts
def cold_and_warm(
    config: TTAConfig, work: Path, part: str, name: str, args: dict[str, Any]
) -> list[dict[str, Any]]:
    """One train command (`run_train`'s args but the cache) twice into a new compilation
    cache `work/cache-NAME`: cold (empty), then warm, whose `same_bits_as_cold` compares
    the final states' hashes."""
    cache = work / f"cache-{name}"
    cache.mkdir()
    records: list[dict[str, Any]] = []
    for phase in ("cold", "warm"):
        rec = run_train(config, work, f"{part}-{name}-{phase}", {**args, "cache": str(cache)}, None)
        rec = {**rec, "part": part, "cache": phase, "xla_ops": CLI_DEFAULT}
        if phase == "warm":
            rec["same_bits_as_cold"] = rec["state_hash"] == records[-1]["state_hash"]
        records.append(rec)
        _print(rec)
    return records


def tta_part(config: TTAConfig, work: Path) -> list[dict[str, Any]]:
    records = []
    for seed in config.seeds:
        records += cold_and_warm(config, work, "tta", f"seed{seed}", {"seed": seed})
    for phase in ("cold", "warm"):
        records.append(median_record([r for r in records if r["cache"] == phase], phase))
    return records


def seeds_part(config: TTAConfig, work: Path) -> list[dict[str, Any]]:
    records = []
    for n in config.seed_counts:
        args = {"seed": config.seeds[0], "seeds": n, "total": config.seeds_total_timesteps}
        records += cold_and_warm(config, work, "seeds", f"n{n}", args)
    return records


def median_record(runs: list[dict[str, Any]], phase: str) -> dict[str, Any]:
    """The median over seeds of each number (module docstring for unreached thresholds)."""
    rec: dict[str, Any] = {"kind": "median", "part": "tta", "cache": phase}
    rec.update({"xla_ops": CLI_DEFAULT, "seeds": [r["seed"] for r in runs]})
    for key in ("command_s", "cli_command_time_s", "first_call_s", "env_steps_per_s"):
        values = [r[key] for r in runs if r[key] is not None]
        rec[key] = statistics.median(values) if values else None
    return {**rec, **threshold_medians(runs)}


def threshold_medians(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per threshold, the median over `runs` of the time and env steps to it (a run that
    never reached it counts as later than any that did; a median falling on such a run is
    None) and how many reached it."""
    rec: dict[str, Any] = {}
    for mm in THRESHOLDS_MM:
        for key in (f"to_{mm:g}mm_s", f"to_{mm:g}mm_env_steps"):
            m = statistics.median([math.inf if r[key] is None else r[key] for r in runs])
            rec[key] = m if math.isfinite(m) else None
        rec[f"reached_{mm:g}mm"] = sum(r[f"to_{mm:g}mm_s"] is not None for r in runs)
    return rec


def xla_ops_part(config: TTAConfig, work: Path) -> list[dict[str, Any]]:
    records = []
    for mode, value in XLA_OPS.items():
        args = {"seed": config.seeds[0], "cache": "false", "total": config.xla_ops_total_timesteps}
        rec = run_train(config, work, f"xla_ops-{mode}", args, value)
        records.append({**rec, "part": "xla_ops", "cache": "off", "xla_ops": mode})
        _print(records[-1])
    return records


def limit_part(config: TTAConfig, ppo_env_steps_per_s: float | None) -> dict[str, Any]:
    from mara_mjx.bench.limit import LimitConfig, limit_study

    sizes = {"tasks": config.tasks, "drivers": ("train",), "sizes": (config.limit_num_envs,)}
    quick = {k: v for k, v in LimitConfig.QUICK.items() if k != "sizes"} if config.quick else {}
    (rec,) = limit_study(LimitConfig(**{**quick, **sizes}))
    sps = ppo_env_steps_per_s
    return {
        "kind": "limit",
        "part": "limit",
        **rec,
        "ppo_env_steps_per_s": sps,
        "ppo_fraction_of_bound": sps / rec["bound_env_steps_per_s"] if sps else None,
    }


def peers_part(config: TTAConfig, mjx_env_steps_per_s: float | None) -> list[dict[str, Any]]:
    """C MuJoCo's train-driver work against the limit part's MJX rate, then brax's PPO
    against ours (module docstring); records of kind "peer"."""
    from mara_mjx.bench.peers import PeersConfig, peers_study
    from mara_mjx.bench.ppo import BraxStudyConfig, brax_study

    task = config.tasks[0]
    c_config = PeersConfig(tasks=(task,), drivers=("train",), skip_mjx=True)
    brax_config = BraxStudyConfig(tasks=(task,))
    if config.quick:
        c_config = c_config.replace(quick=True, **PeersConfig.QUICK)
        brax_config = brax_config.replace(quick=True, **BraxStudyConfig.QUICK)
    if config.peers_total_timesteps:
        brax_config = brax_config.replace(total=config.peers_total_timesteps)
    (c,) = peers_study(c_config.replace(sizes=(config.limit_num_envs,)))
    mjx = mjx_env_steps_per_s
    c = {**c, "mjx_env_steps_per_s": mjx, "mjx_over_c": mjx / c["env_steps_per_s"] if mjx else None}
    return [{"kind": "peer", "part": "peers", **r} for r in (c, *brax_study(brax_config))]


def tta_study(config: TTAConfig) -> list[dict[str, Any]]:
    """The parts of the module docstring, in order; the limit and peers parts last."""
    check_train_args(config.train_args, config.tasks[0], config.preset, build_env=True)
    if config.work_dir:
        Path(config.work_dir).mkdir(parents=True, exist_ok=True)
    folder = tempfile.mkdtemp(prefix="tta-", dir=config.work_dir or None)
    records: list[dict[str, Any]] = []
    try:
        if "tta" in config.parts:
            records += tta_part(config, Path(folder))
        if "xla_ops" in config.parts:
            records += xla_ops_part(config, Path(folder))
        if "seeds" in config.parts:
            records += seeds_part(config, Path(folder))
        if "limit" in config.parts:
            warm = [r for r in records if r["kind"] == "median" and r["cache"] == "warm"]
            records.append(limit_part(config, warm[0]["env_steps_per_s"] if warm else None))
        if "peers" in config.parts:
            limit = [r for r in records if r["kind"] == "limit"]
            records += peers_part(config, limit[0]["env_steps_per_s"] if limit else None)
    finally:
        if not config.work_dir:
            import shutil

            shutil.rmtree(folder, ignore_errors=True)
    if config.work_dir:
        print(f"run folders, caches and logs kept in {folder}")
    return records


def _print(r: dict[str, Any]) -> None:
    seeds = f" x {r['num_seeds']} seeds" if r.get("num_seeds") else ""
    print(
        f"{r['part']:7s} seed {r['seed']}{seeds} {r['cache']:4s} {r['xla_ops']:17s}"
        f" 5 mm at {secs(r['to_5mm_s'])}, 1 mm at {secs(r['to_1mm_s'])},"
        f" command {r['command_s']:.1f} s, {mega(r['env_steps_per_s'])} env steps/s,"
        f" state {r['state_hash']}, training {r.get('training_hash')}",
        flush=True,
    )


STUDY = Study(
    "tta", TTAConfig, tta_study, TTA_TABLE, "time to accuracy from command start, cold and warm"
)
