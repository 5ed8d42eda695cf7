"""The CLIs' help and flags as a user meets them: the train CLI's short --help with the
task's preset values, and an old flag spelling still accepted with a note
(test_layout.py checks that every flag is spelled with underscores). In-process parsers
only: nothing compiles."""

from __future__ import annotations

import re

import pytest

import mara_mjx
from mara_mjx import export, train
from mara_mjx.ppo.config import PRESETS, default_preset


def test_the_old_spelling_still_parses_with_a_note(capsys):
    args = export.build_parser().parse_args(["run", "out.onnx", "--drop-ik-finish"])
    assert args.drop_ik_finish is True
    assert "--drop-ik-finish is deprecated; use --drop_ik_finish" in capsys.readouterr().err


@pytest.mark.parametrize("task", mara_mjx.registered())
def test_train_help_is_short_and_shows_the_tasks_preset(task):
    preset = default_preset(task)
    text = train.build_parser(["--env", task]).format_help()
    assert len(text.splitlines()) <= 150, len(text.splitlines())
    words = " ".join(text.split())
    assert f"PPO defaults shown: the {preset!r} preset" in words and "--help_all" in text
    total = PRESETS[preset].total_timesteps
    assert re.search(rf"total_timesteps // \(num_envs \* num_steps\)\. \(default:\s+{total}\)",
                     text), text  # fmt: skip
    full = train.build_parser(["--env", task], full=True).format_help()
    assert len(full.splitlines()) > 3 * len(text.splitlines())
    assert "--ik_orient_first" in full and "--ik_orient_first" not in text


def test_hidden_flags_still_parse():
    args = train.build_parser(["--env", "MARA"]).parse_args(
        ["--env", "MARA", "--gamma", "0.5", "--num_processes", "2"]
    )
    assert getattr(args, "ppo.gamma") == 0.5 and args.num_processes == 2


def test_an_explicit_preset_sets_the_defaults_shown():
    text = train.build_parser(["--env", "MARA", "--preset", "cpu"]).format_help()
    assert "the 'cpu' preset" in " ".join(text.split()) and "3000000" in text
