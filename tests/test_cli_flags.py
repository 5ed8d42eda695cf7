"""The CLIs' help, flags and plots as a user meets them: the train CLI's short --help with
the task's preset values, an old flag spelling still accepted with a note, the restart
marks of the training plots
(test_layout.py checks that every flag is spelled with underscores). In-process parsers
only: nothing compiles."""

from __future__ import annotations

import re

import pytest

import mara_mjx
from mara_mjx.cli import export, train, train_plan
from mara_mjx.ppo.presets import PRESETS, default_preset


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
    total = PRESETS[preset].ppo.total_timesteps
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


def test_plots_mark_synchronised_restarts_only_where_they_are_few(tmp_path, monkeypatch):
    """Dashed lines where every episode restarts together; none when there would be
    thousands (the paper's preset: one env, a restart every 1,024 env steps)."""
    import matplotlib.axes

    from mara_mjx.ppo import logger

    rows = ["update,env_steps,reward_mean,entropy,det_error_mm"]
    rows += [f"{u},{u * 1024},-0.5,1.0,{100.0 / u}" for u in range(1, 301)]
    (tmp_path / "progress.csv").write_text("\n".join(rows) + "\n")
    lines: list[float] = []
    real = matplotlib.axes.Axes.axvline
    monkeypatch.setattr(
        matplotlib.axes.Axes, "axvline", lambda ax, x, **k: lines.append(x) or real(ax, x, **k)
    )
    logger.save_plots(tmp_path / "progress.csv", tmp_path / "few", "t", reset_every=10 * 1024)
    assert len(lines) == 3 * 30  # 30 restarts, in each of the three plots
    lines.clear()
    written = logger.save_plots(tmp_path / "progress.csv", tmp_path / "many", "t", 1024)
    assert lines == [] and all(p.read_bytes()[:4] == b"\x89PNG" for p in written)


def test_the_help_pre_scan_leaves_bad_command_lines_to_the_parser():
    assert train_plan.preset_of(["--env"]) == "default"  # no value: the real parser says so
    assert train_plan.preset_of(["--env", "MARA"]) == "ik_finish"
    assert train_plan.preset_of(["--env", "MARA", "--preset", "cpu"]) == "cpu"
    assert train_plan.preset_of(["--resume", "runs/x"]) == "default"
