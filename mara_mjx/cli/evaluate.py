"""The paper's accuracy table for a checkpoint: python -m mara_mjx.evaluate CHECKPOINT

    python -m mara_mjx.evaluate runs/MARA-20250101-120000            # newest checkpoint
    python -m mara_mjx.evaluate runs/.../checkpoints/ckpt_00000763.npz --episodes 10
    python -m mara_mjx.evaluate RUN --driver real --velocity 0.3      # on the real-speed driver
    python -m mara_mjx.evaluate RUN_OF_SEEDS    # a --seeds N run: every seed, and across seeds

Runs the deterministic policy (the Gaussian mean) in `--episodes` (10) episodes that start
from the reset pose perturbed by a uniform joint noise of half-width `--noise` (0.02 rad)
so that they differ, all batched in one vmap; each episode stops at the first step where
every axis of |e| is within `--tolerance_mm` (5 mm), or at the horizon. Prints mean +- std
per axis of the final position error (mm) and, for the Orient tasks, of the orientation
error (deg), in the layout of the spec's section 7 with the paper's numbers beside them,
and writes JSON (config, versions, per-episode numbers, summary) to --json (default
<run folder>/eval-<checkpoint>-<driver>.json).

Env flags (--driver, --velocity, --max_episode_steps, ...) override the checkpoint's env
config, e.g. to run a policy trained with the train driver on the real-speed driver.

A run of several seeds (`train --seeds N`): every seed's newest checkpoint in one vmapped
evaluation; prints one row per seed and the mean and worst seed per axis, and writes
JSON and markdown (default <run folder>/eval-seeds-<driver>.json, .md; mara_mjx.cli.seeds).

Random-target tasks (MARARandomTarget, ...): 1,000 held-out target poses instead, each
episode run to the horizon, with per-axis mean, median, 95th percentile and worst error,
JSON, markdown and a figure (`mara_mjx.ppo.target_eval`).

An exported policy file (`python -m mara_mjx.export`, .onnx or .npz) in place of the
checkpoint runs that file in the same closed loop, the same episodes and the same report
(`mara_mjx.deploy.in_the_loop`: onnxruntime or the runner's numpy, one call per env step
batched over the episodes), in the env of its metadata (`--env NAME` for another of the
same observation layout); the report names the file and its sha256 instead of a
checkpoint, and goes by default beside the file (eval-<file stem>-<driver>.json):

    python -m mara_mjx.evaluate policy.onnx --driver real --episodes 100

Where the report goes is checked before anything runs: --json must name a file, not a
folder, a checkpoint or a file of a run folder (config.json, progress.csv, eval.json, ...);
an existing file is replaced only if it is an earlier report of this command (re-running
an evaluation replaces its report), or with --overwrite (`mara_mjx.runtime.outputs.check_output`).
Ctrl-C (or SIGTERM) stops it with one line and exit status 130 (143), writing nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from mara_mjx.cli import seeds
from mara_mjx.cli.common import (
    Section,
    UserError,
    add_cache_argument,
    add_checkpoint_argument,
    add_flags,
    check_rate_limit,
    configure_jax,
    env_overrides,
    overrides,
    run_cli,
    uses_real_driver,
)
from mara_mjx.deploy import in_the_loop
from mara_mjx.envs.base import EnvConfig
from mara_mjx.envs.mara import is_orient_task
from mara_mjx.envs.random_target import is_random_target
from mara_mjx.envs.randomize import RandomizeConfig
from mara_mjx.envs.rewards import RewardParams
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo import policy as policy_io
from mara_mjx.ppo import seed_eval, target_eval
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import PAPER_RESULTS, evaluate, format_table
from mara_mjx.runtime import files, outputs, runs

PROG = "mara_mjx.evaluate"
SECTIONS = (
    Section("eval", EvalConfig),
    Section("env", EnvConfig, exclude=("reward", "randomization")),
    Section("env", RewardParams),
    Section("randomization", RandomizeConfig),
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m mara_mjx.evaluate",
        description="The paper's accuracy table (spec section 7) for a PPO checkpoint "
        "or an exported policy file (.onnx, .npz).",
        allow_abbrev=False,
    )
    add_checkpoint_argument(parser)
    parser.add_argument(
        "--json",
        metavar="PATH",
        help="where to write the JSON report "
        "(default: <run folder>/eval-<checkpoint>-<driver>.json); never a checkpoint or a "
        "run folder's own file; an existing file only if it is an earlier report",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the file --json names even if it is not an earlier report of this "
        "command (still never a checkpoint or a run folder's own file)",
    )
    parser.add_argument(
        "--env",
        dest="env_name",
        metavar="NAME",
        help="for an exported file: the registered env to run it in (default: the export's)",
    )
    add_flags(parser, SECTIONS)
    add_cache_argument(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return runs.run_reporting(lambda: _main(args), PROG, "report")


def _main(args: argparse.Namespace) -> int:
    export = load_export(args.checkpoint)  # None: a checkpoint, run folder or seeds run
    if export is None and args.env_name:
        raise UserError("--env is for an exported file; a checkpoint runs in its own env")
    if export is None:
        real = uses_real_driver(args, args.checkpoint)
    else:
        given = overrides(args, "env").get("driver")
        real = (given or export.meta["env_config"].get("driver", "train")) == "real"
    configure_jax(args.compilation_cache, real)
    group = None if export else seeds.group_of(args.checkpoint)  # several seeds: each newest
    path = None if group or export else ckpt.find_checkpoint(args.checkpoint)
    arrays, meta = ckpt.load_checkpoint(path) if path else (None, None)
    eval_overrides = overrides(args, "eval")
    if export is not None and eval_overrides.get("commit_rad", -1.0) == -1.0:
        eval_overrides["commit_rad"] = in_the_loop.commit_rad(export.meta)  # the file's rule
    try:
        config = EvalConfig().replace(**eval_overrides)
    except ValueError as e:
        raise UserError(f"invalid eval config: {e}") from e
    if config.rate_limit:  # (reads the checkpoint's driver only then)
        check_rate_limit(config, "real" if real else "train")
    if group is not None:
        top = Path(args.checkpoint)
        return evaluate_seeds_run(
            top, group, config, env_overrides(args), args.json, args.overwrite
        )
    if export is not None:
        try:
            env = in_the_loop.make_env(export, args.env_name, **env_overrides(args))
        except in_the_loop.InTheLoopError as e:
            raise UserError(str(e)) from e
        name, policy, folder, stem = env.name, export.policy, export.path.parent, export.path.stem
        source = {"exported_policy": export.describe()}
        heading = f"exported policy: {export.path} (sha256 {export.sha256})"
    else:
        env = runs.make_env(meta, **env_overrides(args))
        name, folder, stem = meta["env_name"], runs.run_dir_of(path), path.stem
        policy = policy_io.policy_from_checkpoint(arrays, meta)
        source = {
            "checkpoint": str(path),
            **{k: meta[k] for k in ("ppo", "policy", "curriculum")},
            "trained": meta["progress"],
            "training_versions": meta.get("versions"),
        }
        heading = f"checkpoint: {path}"
    driver = env.config.driver
    if is_random_target(env):  # held-out target poses instead of the paper's table
        default = folder / f"eval-{stem}-{driver}-targets.json"
        out = check_report(Path(args.json) if args.json else default, args.overwrite)
        for suffix in (".md", ".png"):  # written beside it
            what = f"{suffix[1:]} file beside the report"
            outputs.check_output(
                out.with_suffix(suffix), what, outputs.companion_of(out), args.overwrite
            )
    else:
        default = folder / f"eval-{stem}-{driver}.json"
        out = check_report(Path(args.json) if args.json else default, args.overwrite)
    if is_random_target(env):
        return target_eval.run(
            name=name,
            source=source,
            heading=heading,
            env=env,
            policy=policy,
            eval_overrides=eval_overrides,
            json_path=str(out),
        )
    print(heading)
    print(
        f"env: {name}, driver {env.config.driver!r}"
        + (f", velocity {env.config.velocity:g} rad/s" if env.config.driver == "real" else "")
        + f", horizon {env.max_episode_steps} steps",
        flush=True,
    )
    result = evaluate(env, policy, config)
    orientation = is_orient_task(env)
    print(format_table(name, result, orientation, config))
    first = {k: v for k, v in source.items() if k in ("checkpoint", "exported_policy")}
    report = {
        **first,
        "env_name": name,
        "env_config": env.config.to_dict(),
        "eval": config.to_dict(),
        **{k: v for k, v in source.items() if k not in first},
        **runs.provenance(),
        "episodes": result.episodes(),
        "summary": result.summary(),
        "paper": PAPER_RESULTS.get(name),
    }
    runs.write_json(out, report)
    print(f"wrote {out}")
    return 0


def load_export(arg: str) -> in_the_loop.Export | None:
    """The exported file `arg` names (in_the_loop.is_export_path), else None."""
    if not in_the_loop.is_export_path(arg):
        return None
    try:
        return in_the_loop.load(arg)
    except in_the_loop.InTheLoopError as e:
        raise UserError(str(e)) from e


def check_report(out: Path, overwrite: bool) -> Path:
    """`out` if the JSON report may be written there (outputs.check_output), else UserError."""
    return outputs.check_output(out, "--json report", outputs.is_report, overwrite)


def evaluate_seeds_run(
    top: Path,
    group: dict[str, Any],
    eval_config: Any,
    env_overrides: dict,
    json_path,
    overwrite: bool = False,
) -> int:
    """`python -m mara_mjx.evaluate RUN` on a multi-seed run: every seed's newest
    checkpoint in one vmapped evaluation, the summary across seeds printed and written
    (default <RUN>/eval-seeds-<driver>.json and .md; an existing file there only if it
    is an earlier report, or with `overwrite`: outputs.check_output)."""
    seed_ids = [int(s) for s in group["seeds"]]
    paths = [ckpt.find_checkpoint(seeds.folder(top, s)) for s in seed_ids]
    loaded = [ckpt.load_checkpoint(p) for p in paths]
    env = runs.make_env(loaded[0][1], **env_overrides)
    if is_random_target(env):
        raise UserError(
            "a multi-seed run of a random-target task is evaluated one seed at a time: "
            f"python -m mara_mjx.evaluate {top}/seed_<s> (seeds {seed_ids})"
        )
    out = Path(json_path) if json_path else top / f"eval-seeds-{env.config.driver}.json"
    outputs.check_output(out, "--json report", outputs.is_report, overwrite)
    md = out.with_suffix(".md")
    outputs.check_output(md, "markdown report", outputs.companion_of(out), overwrite)
    name = loaded[0][1]["env_name"]
    print(f"run: {top}, {len(seed_ids)} seeds; checkpoints: {[str(p) for p in paths]}")
    print(f"env: {name}, driver {env.config.driver!r}, horizon {env.max_episode_steps} steps")
    policy = seed_eval.stack_policies([policy_io.policy_from_checkpoint(a, m) for a, m in loaded])
    results = seed_eval.evaluate_seeds(env, policy, eval_config, len(seed_ids))
    rows = [
        seed_eval.seed_row(s, r, m["progress"].get("milestones", {}))
        for s, r, (_, m) in zip(seed_ids, results, loaded, strict=True)
    ]
    orientation = is_orient_task(env)
    report = seed_eval.summarise(name, orientation, rows, eval_config.to_dict())
    report.update(
        run=str(top),
        env_config=env.config.to_dict(),
        **runs.provenance(),
        checkpoints=[
            {"seed": s, "checkpoint": str(p), "trained": m["progress"], "episodes": r.episodes()}
            for s, p, r, (_, m) in zip(seed_ids, paths, results, loaded, strict=True)
        ],
    )
    runs.write_json(out, report)
    files.write_atomic(md, seed_eval.markdown(report) + "\n")
    print(seed_eval.markdown(report))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    from mara_mjx.runtime import supervise

    sys.exit(supervise.run(lambda: run_cli(main, PROG), PROG))
