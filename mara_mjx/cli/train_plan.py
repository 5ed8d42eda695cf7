"""The train CLI's command line (`python -m mara_mjx.train`): its flags, generated from
the configs (TrainConfig's PPOConfig, PolicyConfig and CurriculumConfig, all three under
`--ppo.` as before they were split; RunConfig, EvalConfig, the env's EnvConfig,
RewardParams and RandomizeConfig; `--help` lists the main ones with the defaults of the
preset the task trains, `--help_all` every one), and the `Plan` resolved from them: the
task, its preset with the flags on top, the run folder, or on `--resume` the
checkpoint's config with only run.* and eval.* changed."""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import mara_mjx
from mara_mjx.cli import seeds
from mara_mjx.cli.common import (
    Section,
    UserError,
    add_cache_argument,
    add_flags,
    check_rate_limit,
    env_overrides,
    overrides,
    parse_bool,
)
from mara_mjx.envs.base import EnvConfig
from mara_mjx.envs.randomize import RandomizeConfig
from mara_mjx.envs.rewards import RewardParams
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.config import (
    CurriculumConfig,
    EvalConfig,
    PolicyConfig,
    PPOConfig,
    RunConfig,
    TrainConfig,
)
from mara_mjx.ppo.presets import PRESETS, default_preset
from mara_mjx.runtime import distributed, runs

SECTIONS = (
    # TrainConfig's three sections share `--ppo.` (their flags before the split)
    Section("ppo", PPOConfig, defaults=PRESETS["default"].ppo),
    Section("ppo", PolicyConfig, defaults=PRESETS["default"].policy),
    Section("ppo", CurriculumConfig, defaults=PRESETS["default"].curriculum),
    Section("run", RunConfig),
    Section("eval", EvalConfig),
    Section("env", EnvConfig, exclude=("reward", "randomization")),
    Section("env", RewardParams),
    Section("randomization", RandomizeConfig),
)


@dataclasses.dataclass(frozen=True)
class Plan:
    """Everything resolved from the command line (and the checkpoint, on resume)."""

    env_name: str
    env_overrides: dict[str, Any]
    config: TrainConfig
    """The algorithm, the policy's parametrisation and the curriculum (`--ppo.*`)."""
    run: RunConfig
    eval: EvalConfig
    out: Path
    checkpoint: Path | None = None
    source_run: Path | None = None
    preset: str = ""
    """The PPO preset the run started from (its name, as config.json records it)."""


BRIEF = {
    "ppo": ("seed", "total_timesteps", "num_envs", "num_steps", "learning_rate"),
    "run": ("out", "seeds", "devices", "checkpoint_every", "evaluate", "progress"),
    "eval": ("episodes",),
    "env": ("driver", "velocity", "max_episode_steps", "randomize"),
}
"""The flags a short --help shows (--help_all: every flag)."""


def preset_of(argv: list[str] | None) -> str:
    """The preset a command line trains: --preset, else its --env's (default_preset), else
    "default" (no --env given, or a command line the real parser will reject)."""
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--env")
    pre.add_argument("--preset")

    def ignore(message: str) -> None:
        raise ValueError(message)

    pre.error = ignore  # e.g. `--env` without a value: the real parser says so
    try:
        known, _ = pre.parse_known_args(sys.argv[1:] if argv is None else argv)
    except ValueError:
        return "default"
    if known.preset in PRESETS:
        return known.preset
    return default_preset(known.env) if known.env in mara_mjx.registered() else "default"


def build_parser(argv: list[str] | None = None, full: bool = False) -> argparse.ArgumentParser:
    """The train CLI's parser. Its help shows the PPO defaults of the preset `argv` trains
    (preset_of) and, unless `full`, only the BRIEF flags; every flag parses either way."""
    preset = preset_of(argv)
    sections = [
        dataclasses.replace(
            s,
            defaults=section_of(PRESETS[preset], s.cls) if s.name == "ppo" else s.defaults,
            brief=None if full else BRIEF.get(s.name, ()),
        )
        for s in SECTIONS
    ]
    parser = argparse.ArgumentParser(
        prog="python -m mara_mjx.train",
        description=f"Train PPO on a MARA task. PPO defaults shown: the {preset!r} preset"
        + (" (give --env to see the task's own)." if preset == "default" else ".")
        + ("" if full else " A short list: --help_all shows every flag."),
        allow_abbrev=False,
    )
    parser.add_argument(
        "--env",
        choices=mara_mjx.registered(),
        help="registered env to train on (required unless --resume)",
    )
    parser.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        help="PPO preset (default: the task's own, as `ppo.presets.default_preset` picks it); "
        "flags override its fields",
    )
    parser.add_argument(
        "--resume",
        metavar="RUN_DIR_OR_CHECKPOINT",
        help="continue a run exactly from a checkpoint file or a run folder's newest "
        "checkpoint; only run.* and eval.* options may change (output goes to the "
        "checkpoint's run folder unless --out is given)",
    )
    parser.add_argument(
        "--verbose",
        type=parse_bool,
        nargs="?",
        const=True,
        default=False,
        metavar="{true,false}",
        help="print the whole resolved config at the start (it is always written to the "
        "run folder's config.json)",
    )

    class HelpAll(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            build_parser(argv, full=True).print_help()
            parser.exit()

    parser.add_argument("--help_all", nargs=0, action=HelpAll, help="show every flag and exit")
    add_flags(parser, sections)
    add_cache_argument(parser)
    if full:
        distributed.add_arguments(parser)
    else:  # parsed, not listed
        hidden = argparse.ArgumentParser(add_help=False)
        distributed.add_arguments(hidden)
        for action in hidden._actions:
            action.help = argparse.SUPPRESS
            parser._add_action(action)
    return parser


def section_of(config: TrainConfig, cls: type) -> Any:
    """The section of `config` that is a `cls` (PPOConfig, PolicyConfig, ...)."""
    return next(v for v in vars(config).values() if isinstance(v, cls))


def resolve(args: argparse.Namespace) -> Plan:
    """The plan from flags, presets and (on resume) the checkpoint; UserError if invalid."""
    given = {s.name: overrides(args, s.name) for s in SECTIONS}
    if args.resume is None:
        if args.env is None:
            raise UserError(f"--env is required; choose one of {list(mara_mjx.registered())}")
        preset = PRESETS[args.preset or default_preset(args.env)]
        config = _build("PPO config", lambda: preset.replace(**given["ppo"]))
        run = _build("run config", lambda: RunConfig().replace(**given["run"]))
        evaluation = _build("eval config", lambda: EvalConfig().replace(**given["eval"]))
        check_rate_limit(evaluation, env_overrides(args).get("driver", "train"))
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        out = Path(run.out or f"runs/{args.env}-{stamp}")
        name = args.preset or default_preset(args.env)
        if name == "distill" and not config.curriculum.teacher:
            raise UserError(
                "the distill preset imitates a trained policy: give --teacher RUN (a run of "
                f"{args.env}, e.g. one `python -m mara_mjx.train --env {args.env}` made; with "
                "--seeds, one trained with the same --seed and --seeds)"
            )
        if config.curriculum.teacher:  # recorded absolute: a resume from elsewhere finds it
            config = config.replace(teacher=str(Path(config.curriculum.teacher).resolve()))
        return Plan(args.env, env_overrides(args), config, run, evaluation, out, preset=name)

    checkpoint, top, group_run = seeds.find_resume(args.resume, given["run"])
    _, meta = ckpt.load_checkpoint(checkpoint)
    if args.preset is not None:
        raise UserError("--preset cannot be combined with --resume (the run keeps its config)")
    if args.env is not None and args.env != meta["env_name"]:
        raise UserError(f"--env {args.env} differs from the checkpoint's env {meta['env_name']}")
    for section in ("ppo", "env", "randomization"):
        if given[section]:
            names = ", ".join(f"{section}.{k}" for k in given[section])
            raise UserError(
                f"cannot change {names} when resuming: it would change the results; "
                "start a new run instead (only run.* and eval.* may change)"
            )
    config = _build("PPO config of the checkpoint", lambda: TrainConfig.from_meta(meta))
    run = {**meta["run"], **group_run, **given["run"]}
    run = _build("run config", lambda: RunConfig.from_dict(run))
    evaluation = _build(
        "eval config", lambda: EvalConfig.from_dict({**meta["eval"], **given["eval"]})
    )
    source = top or runs.run_dir_of(checkpoint)
    out = Path(given["run"]["out"]) if given["run"].get("out") else source
    run = run.replace(out=str(out))
    env_flags = runs.env_overrides(meta["env_config"])
    check_rate_limit(evaluation, meta["env_config"].get("driver", "train"))
    preset = meta.get("preset", "")
    return Plan(
        meta["env_name"], env_flags, config, run, evaluation, out, checkpoint, source, preset
    )


def _build(what: str, make: Callable[[], Any]) -> Any:
    """make(), with a config's ValueError reported as a user error."""
    try:
        return make()
    except (TypeError, ValueError) as e:
        raise UserError(f"invalid {what}: {e}") from e
