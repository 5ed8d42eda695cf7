"""The train and evaluate CLIs as a user runs them (subprocesses, tiny settings), and
their clear errors on bad input (before anything is compiled).

One tiny training run (4 envs x 8 steps, 2 updates, 16-step episodes) is shared by the
session. Subprocesses share a JAX persistent compilation cache in a temporary folder, so
the resumed run and the evaluation reuse the training run's compiled programs. A
population run and the Orient tasks' default preset train on their own (at the end; the
--seeds runs: tests/test_seeds_cli.py, on another worker).
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from mara_mjx.cli import evaluate as evaluate_cli
from mara_mjx.cli import export as export_cli
from mara_mjx.cli import train as train_cli
from mara_mjx.cli.common import run_cli
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.runtime import outputs, runs

REPO = Path(__file__).resolve().parents[1]
TINY = [
    "--env", "MARA",
    "--num_envs", "4",
    "--num_steps", "8",
    "--total_timesteps", "64",
    "--num_minibatches", "2",
    "--update_epochs", "2",
    "--max_episode_steps", "16",
    "--checkpoint_every", "1",
    "--updates_per_call", "1",
]  # fmt: skip
CKPT1, CKPT2 = (Path(ckpt.CHECKPOINT_DIR) / ckpt.checkpoint_name(u) for u in (1, 2))


def run_module(env: dict[str, str], module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def start_module(env: dict[str, str], module: str, *args: str) -> subprocess.Popen:
    """`python -m module args` in the background (run_module's counterpart)."""
    return subprocess.Popen(
        [sys.executable, "-m", module, *args],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


@pytest.fixture(scope="session")
def trained(cli_env, tmp_path_factory):
    """(run folder, completed process) of the tiny training run."""
    out = tmp_path_factory.mktemp("train") / "run"
    proc = run_module(cli_env, "mara_mjx.train", *TINY, "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-4000:]
    return out, proc


@pytest.fixture(scope="session")
def real_driver_eval(trained, cli_env, tmp_path_factory):
    """The evaluation on the real-speed driver (a long compile on CPU), started in the
    background as soon as the run exists so that it overlaps the other tests."""
    out, _ = trained
    report = tmp_path_factory.mktemp("real") / "eval-real.json"
    args = [str(out), "--driver", "real", "--velocity", "0.3", "--json", str(report)]
    proc = start_module(cli_env, "mara_mjx.evaluate", *args)
    yield proc, report
    if proc.poll() is None:
        proc.kill()
        proc.communicate()


def read_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------------ training


def test_train_writes_logs_checkpoints_plots_and_eval(trained, real_driver_eval):
    out, proc = trained
    assert "Traceback" not in proc.stderr
    assert "step/s" in proc.stderr  # the tqdm progress bar

    config = json.loads((out / "config.json").read_text())
    assert config["env_name"] == "MARA" and config["ppo"]["num_envs"] == 4
    assert config["env_config"]["max_episode_steps"] == 16
    assert config["ppo"]["normalize_obs"] is True  # the 'default' preset
    assert {"python", "jax", "mujoco", "flax", "optax"} <= set(config["versions"])
    assert "git_commit" in config
    first, second = proc.stdout.splitlines()[:2]  # a short header, the config in its file
    assert first.startswith("MARA, preset ") and "seed 0: 4 envs x 8 steps per update" in first
    assert second.startswith("device: ") and f"run folder: {out}" in second
    assert '"env_name"' not in proc.stdout  # the whole config only with --verbose

    rows = read_rows(out / "progress.csv")
    assert [int(r["update"]) for r in rows] == [1, 2]
    assert [int(r["env_steps"]) for r in rows] == [32, 64]
    for column in (
        "time_s", "steps_per_s", "reward_mean", "episode_return", "distance_mm",
        "pos_err_x_mm", "pos_err_y_mm", "pos_err_z_mm", "det_error_mm", "collision_rate",
        "entropy", "policy_loss", "value_loss", "learning_rate", "approx_kl", "clip_frac",
        "nonfinite_actions",
    ):  # fmt: skip
        assert column in rows[0], column
    assert "ori_err_x_deg" not in rows[0]  # MARA has no orientation task
    for r in rows:
        for column in ("entropy", "value_loss", "learning_rate", "distance_mm", "time_s"):
            assert np.isfinite(float(r[column])), column
    # 16-step episodes end at update 2 (env steps 9-16 of each env).
    assert float(rows[1]["episodes"]) == 4 and np.isfinite(float(rows[1]["episode_return"]))
    assert float(rows[1]["time_s"]) >= float(rows[0]["time_s"]) > 0

    for c, update in ((CKPT1, 1), (CKPT2, 2)):
        _, meta = ckpt.load_checkpoint(out / c)
        assert meta["progress"]["update"] == update
        assert meta["progress"]["env_steps"] == 32 * update
        assert meta["ppo"] == config["ppo"] and meta["env_config"] == config["env_config"]
    assert list((out / "tb").glob("events.out.tfevents.*"))
    for name in ("reward.png", "entropy.png"):
        assert (out / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    report = json.loads((out / "eval.json").read_text())
    assert len(report["episodes"]) == 10
    assert "| MARA (this policy) |" in proc.stdout and "| MARA (paper) |" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert "time_to_accuracy" in summary and summary["training_last_update"]["update"] == 2


def test_tiny_training_gives_the_presplit_bits(trained):
    """The tiny MARA run (preset ik_finish: train_reward, the collision penalty, the bound
    loss, relative actions, the canonical quaternion) ends with the params recorded
    before the PPOConfig split (test_config_split.PRESPLIT; other jax versions: skipped)."""
    from test_config_split import PRESPLIT, check_presplit, checkpoint_digest, same_versions

    if not same_versions():
        pytest.skip(f"reference bits recorded on jax {PRESPLIT['versions']}")
    check_presplit("cli", checkpoint_digest(trained[0] / CKPT2))


def test_resume_reproduces_the_uninterrupted_run(trained, cli_env, tmp_path):
    """Resume a copy of the run from its first checkpoint (as if the command had died
    after logging update 2 but before checkpointing it): the final checkpoint is
    bit-identical and the CSV holds each update once."""
    out, _ = trained
    copy = tmp_path / "resumed"
    shutil.copytree(out, copy)
    (copy / CKPT2).unlink()
    for name in ("eval.json", "summary.json"):
        (copy / name).unlink()
    proc = run_module(cli_env, "mara_mjx.train", "--resume", str(copy), "--progress", "false")
    assert proc.returncode == 0, proc.stderr[-4000:]

    original, _ = ckpt.load_checkpoint(out / CKPT2)
    resumed, meta = ckpt.load_checkpoint(copy / CKPT2)
    assert meta["progress"]["update"] == 2
    assert original.keys() == resumed.keys()
    for name in original:
        np.testing.assert_array_equal(original[name], resumed[name], err_msg=name)

    rows, again = read_rows(out / "progress.csv"), read_rows(copy / "progress.csv")
    assert [r["update"] for r in again] == ["1", "2"]
    timing = {"time_s", "steps_per_s"}
    assert {k: v for k, v in rows[1].items() if k not in timing} == {
        k: v for k, v in again[1].items() if k not in timing
    }
    assert (copy / "eval.json").exists() and (copy / "summary.json").exists()


def test_evaluate_cli_reproduces_the_training_evaluation(trained, cli_env, tmp_path):
    out, _ = trained
    report_path = tmp_path / "eval.json"
    proc = run_module(cli_env, "mara_mjx.evaluate", str(out / CKPT2), "--json", str(report_path))
    assert proc.returncode == 0, proc.stderr[-4000:]
    report = json.loads(report_path.read_text())
    during_training = json.loads((out / "eval.json").read_text())
    assert report["episodes"] == during_training["episodes"]  # same policy, same episodes
    for line in proc.stdout.splitlines():
        if line.startswith("| MARA (this policy)"):
            mean, std = report["summary"]["position_error_mm"].values()
            assert (
                line
                == "| MARA (this policy) | "
                + " | ".join(f"{m:.2f} +- {s:.2f}" for m, s in zip(mean, std, strict=True))
                + " |"
            )
            break
    else:
        pytest.fail(f"no table row in {proc.stdout}")


# ---------------------------------------------------------------------- bad input


def _bad_train_inputs(tmp: Path, run: Path) -> list[tuple[list[str], str]]:
    not_a_folder = tmp / "file.txt"
    not_a_folder.write_text("x")
    garbage = tmp / "garbage.npz"
    garbage.write_bytes(b"not a checkpoint")
    empty = tmp / "empty_run"
    empty.mkdir()
    arrays, meta = ckpt.load_checkpoint(run / CKPT1)
    arrays.pop("params/params/actor/Dense_0/kernel")
    stripped = ckpt.save_checkpoint(tmp / "stripped" / CKPT1, arrays, {**meta})
    edited = tmp / "edited_csv"  # progress.csv without its update column
    shutil.copytree(run, edited)
    (edited / "progress.csv").write_text("step,reward\n1,0.5\n")
    tiny = list(TINY)
    return [
        (["--num_envs", "4"], "--env is required"),
        ([*tiny, "--num_minibatches", "3"], "does not divide the batch"),
        ([*tiny, "--velocity", "3"], "velocity"),
        ([*tiny, "--devices", "64"], "devices=64 but only"),
        ([*tiny, "--out", str(not_a_folder / "run")], "cannot write to the output folder"),
        ([*tiny, "--out", str(run)], "already holds a run"),
        (["--resume", str(tmp / "missing")], "does not exist"),
        (["--resume", str(garbage)], "corrupt"),
        (["--resume", str(empty)], "has no checkpoints"),
        (["--resume", str(run), "--learning_rate", "1e-3"], "cannot change ppo.learning_rate"),
        (["--resume", str(stripped), "--out", str(tmp / "o")], "has no array"),
        (["--resume", str(edited)], "has no 'update' column; it cannot be continued"),
    ]


def test_bad_train_input_fails_fast_with_a_clear_message(trained, tmp_path, capsys, compiled):
    out, _ = trained
    for argv, message in _bad_train_inputs(tmp_path, out):
        compiled.clear()
        code = run_cli(train_cli.main, train_cli.PROG, argv)
        err = capsys.readouterr().err
        assert code == 2, argv
        assert message in err and err.startswith("mara_mjx.train: error:"), (argv, err)
        assert "Traceback" not in err
        ours = [n for n in compiled if n in ("jit(run)", "jit(init)", "jit(evaluate)")]
        assert not ours, (argv, ours)


def test_bad_evaluate_input_fails_fast_with_a_clear_message(trained, tmp_path, capsys, compiled):
    out, _ = trained
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"PK\x03\x04 truncated zip")
    cases = [
        ([str(tmp_path / "missing.npz")], "does not exist"),
        ([str(garbage)], "corrupt"),
        ([str(out), "--episodes", "0"], "episodes"),
        ([str(out), "--driver", "real", "--velocity", "9"], "velocity"),
    ]
    for argv, message in cases:
        compiled.clear()
        code = run_cli(evaluate_cli.main, evaluate_cli.PROG, argv)
        err = capsys.readouterr().err
        assert code == 2 and message in err, (argv, err)
        assert err.startswith("mara_mjx.evaluate: error:") and "Traceback" not in err
        assert "jit(evaluate)" not in compiled


def test_unknown_env_as_a_user_sees_it(cli_env):
    proc = run_module(cli_env, "mara_mjx.train", "--env", "MARX")
    assert proc.returncode == 2
    assert "invalid choice: 'MARX'" in proc.stderr and "MARACollisionOrient" in proc.stderr
    assert "Traceback" not in proc.stderr and "MARA:" not in proc.stdout  # nothing ran


def test_corrupt_checkpoint_as_a_user_sees_it(cli_env, tmp_path):
    garbage = tmp_path / "ckpt.npz"
    garbage.write_bytes(b"\x00" * 100)
    proc = run_module(cli_env, "mara_mjx.evaluate", str(garbage))
    assert proc.returncode == 2
    assert "corrupt" in proc.stderr and str(garbage) in proc.stderr
    assert "Traceback" not in proc.stderr


def test_prune_keeps_the_newest_checkpoints(tmp_path):
    folder = tmp_path / ckpt.CHECKPOINT_DIR
    folder.mkdir()
    for update in (5, 10, 15, 20):
        (folder / ckpt.checkpoint_name(update)).write_bytes(b"")
    runs.prune_checkpoints(tmp_path, keep=2)
    assert [p.name for p in ckpt.list_checkpoints(tmp_path)] == [
        ckpt.checkpoint_name(15),
        ckpt.checkpoint_name(20),
    ]


def test_evaluate_cli_on_the_real_driver(real_driver_eval):
    """A policy trained with the train driver, evaluated on the real-speed driver."""
    proc, report_path = real_driver_eval
    stdout, stderr = proc.communicate(timeout=600)
    assert proc.returncode == 0, stderr[-4000:]
    assert "driver 'real', velocity 0.3 rad/s" in stdout
    assert "| task | x | y | z |" in stdout
    assert "| MARA (paper) | 5.74 +- 6.73 | 6.78 +- 5.27 | 6.38 +- 4.72 |" in stdout
    report = json.loads(report_path.read_text())
    assert report["env_config"]["driver"] == "real"
    assert report["env_config"]["velocity"] == 0.3
    assert report["eval"]["episodes"] == len(report["episodes"]) == 10
    errors = np.array([e["position_error_mm"] for e in report["episodes"]])
    np.testing.assert_allclose(
        report["summary"]["position_error_mm"]["mean"], errors.mean(0), rtol=1e-6
    )
    assert all(1 <= e["steps"] <= 16 for e in report["episodes"])
    assert {"jax", "mujoco"} <= set(report["versions"])


def test_bad_seeds_fail_fast_with_a_clear_message(trained, tmp_path, capsys, compiled):
    from mara_mjx.cli import seeds
    from mara_mjx.cli.common import UserError

    out, _ = trained
    tiny = [*TINY, "--out", str(tmp_path / "o")]
    cases = [
        ([*tiny, "--seeds", "0"], "seeds must be an int >= 1"),
        ([*tiny, "--seeds", "-3"], "seeds must be an int >= 1"),
        ([*tiny, "--seeds", "2", "--devices", "2"], "use --devices 0 (all devices) or"),
        ([*tiny, "--seeds", "2", "--num_processes", "2", "--process_id", "0",
          "--coordinator", "localhost:1"], "cannot be combined with several processes"),
        (["--resume", str(out), "--seeds", "2"], "--seeds cannot change when resuming"),
    ]  # fmt: skip
    for argv, message in cases:
        compiled.clear()
        code = run_cli(train_cli.main, train_cli.PROG, argv)
        err = capsys.readouterr().err
        assert code == 2, (argv, err)
        assert message in err and err.startswith("mara_mjx.train: error:"), (argv, err)
        assert len(err.strip().splitlines()) == 1 and not compiled, (argv, err, compiled)
    with pytest.raises(SystemExit) as exit_:
        train_cli.main([*tiny, "--seeds", "two"])
    assert exit_.value.code == 2 and "seeds: invalid int value: 'two'" in capsys.readouterr().err
    with pytest.raises(
        UserError, match=r"--seeds 3 does not divide over the 2 devices.*multiple of 2"
    ):
        seeds.check(3, devices=0, available=2)
    seeds.check(4, devices=0, available=2)  # 2 seeds per device
    seeds.check(3, devices=1, available=2)  # every seed on one device


def test_the_preset_follows_the_task_unless_one_is_given():
    """A *RandomTarget position env trains with 'random_target_plan' (the IK residual, the
    plan and its restarts at 5e7 steps; MARACollisionRandomTarget with the collision guard,
    'random_target_plan_guard'), an *OrientRandomTarget one with 'random_target_orient'
    and its deployed plan and restarts ('random_target_orient_plan'), the fixed Orient
    tasks with 'orient_first', MARACollision with 'staggered_ik_finish' and MARA with
    'ik_finish'; --preset and flags win. No compile."""

    def ppo(*argv):  # the TrainConfig
        return train_cli.resolve(train_cli.build_parser().parse_args([*argv, "--out", "x"])).config

    def fields(*argv):  # its fields, all sections
        return types.SimpleNamespace(**ppo(*argv).flat())

    assert fields("--env", "MARACollisionRandomTarget").stagger_episodes is True
    orient = fields("--env", "MARACollisionOrientRandomTarget")
    assert orient.stagger_episodes is True and orient.ik_prior == "residual"
    assert orient.ik_gate > 0 and orient.ik_wrap and orient.ik_gate_wrap
    assert (orient.plan_steps, orient.plan_starts) == (16, 16)  # deployed only
    plain = ppo("--env", "MARACollisionOrientRandomTarget", "--preset", "random_target_orient")
    assert ppo("--env", "MARACollisionOrientRandomTarget") == plain.replace(
        plan_steps=16, plan_starts=16)  # fmt: skip
    plain = ppo("--env", "MARAOrientRandomTarget", "--preset", "random_target_orient")
    assert ppo("--env", "MARAOrientRandomTarget") == plain.replace(
        plan_steps=16, plan_starts=16)  # fmt: skip
    # the position tasks: the same machinery at 5e7 steps, exactly what section 53 measured
    planned = ("--preset", "random_target_orient_plan", "--total_timesteps", "50000000")
    assert ppo("--env", "MARARandomTarget") == ppo("--env", "MARARandomTarget", *planned)
    guarded = ppo("--env", "MARACollisionRandomTarget", *planned, "--collision_guard_mm", "5")
    assert ppo("--env", "MARACollisionRandomTarget") == guarded
    assert fields("--env", "MARAOrientRandomTarget", "--ik_gate", "0.05").ik_gate == 0.05
    for task in ("MARAOrient", "MARACollisionOrient"):
        first = fields("--env", task)
        assert ppo("--env", task) == ppo("--env", task, "--preset", "orient_first")
        assert first.ik_orient_first and first.train_ik_gate_roll and first.stagger_episodes
        assert first.train_ik_orient_loose and first.ik_prior == "residual"
        assert first.total_timesteps == fields("--env", "MARA").total_timesteps
    assert fields("--env", "MARAOrient", "--preset", "default").ik_prior == ""
    default = ppo("--env", "MARA", "--preset", "default")
    staggered = default.replace(stagger_episodes=True, ik_finish=0.06)
    assert ppo("--env", "MARACollision") == staggered
    assert ppo("--env", "MARA") == default.replace(ik_finish=0.06)  # the deployed finish
    assert fields("--env", "MARA").stagger_episodes is False
    assert fields("--env", "MARARandomTarget", "--preset", "default").stagger_episodes is False
    flagged = ppo("--env", "MARARandomTarget", "--stagger_episodes", "false")
    assert flagged.curriculum.stagger_episodes is False
    assert flagged.replace(stagger_episodes=True) == ppo("--env", "MARARandomTarget")


def test_rate_limit_without_the_real_driver_is_a_clear_error():
    """--rate_limit true limits steps to the real driver's servo speed: refused (UserError
    naming the fix) on the train driver, accepted with --driver real. No compile."""

    def plan(*argv):
        return train_cli.resolve(train_cli.build_parser().parse_args([*argv, "--out", "x"]))

    with pytest.raises(train_cli.UserError, match="add --driver real, or drop --rate_limit"):
        plan("--env", "MARA", "--rate_limit", "true")
    assert plan("--env", "MARA", "--rate_limit", "true", "--driver", "real").eval.rate_limit


# ------------------------------------------------------------- what a run never loses


def _finished_copy(trained, tmp_path) -> Path:
    out, _ = trained
    copy = tmp_path / "finished"
    shutil.copytree(out, copy)
    return copy


def test_resume_rewrites_progress_csv_inside_the_stop_handler(trained, tmp_path, monkeypatch):
    """Issue 34 item 3: --resume rewrites progress.csv (atomically, test_run_safety.py)
    once Ctrl-C and SIGTERM only ask to stop, so that neither can cut the rewrite; and
    the run folder's lock is given back however the command ends."""
    import signal

    copy = _finished_copy(trained, tmp_path)
    seen = {}

    class Stop(Exception):
        pass

    def logger_(*args, **kwargs):
        seen.update({s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)})
        raise Stop

    monkeypatch.setattr(train_cli.logger, "RunLogger", logger_)
    with pytest.raises(Stop):
        train_cli.main(["--resume", str(copy), "--progress", "false"])
    assert seen == {s: train_cli.STOP._handle for s in seen}, seen
    assert not (copy / outputs.LOCK).exists()


def test_ctrl_c_during_the_final_evaluation_and_a_full_disk_are_one_line(
    trained, tmp_path, monkeypatch, capsys, compiled
):
    """Issue 34 item 12, on --resume of a finished run (which only evaluates again):
    Ctrl-C in the final evaluation exits 130 with what to do, no traceback; a full disk
    (ENOSPC injected) when summary.json is written is one line naming the file. Nothing
    compiles (the evaluation is interrupted before it runs)."""
    import errno
    import os

    from mara_mjx.runtime import files

    copy = _finished_copy(trained, tmp_path)

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train_cli, "evaluate", ctrl_c)
    code = run_cli(train_cli.main, train_cli.PROG, ["--resume", str(copy), "--progress", "false"])
    err = capsys.readouterr().err
    assert code == 130, err
    assert "interrupted during the final evaluation" in err and f"--resume {copy}" in err
    assert "Traceback" not in err

    class FullDisk:  # os, as mara_mjx.runtime.files sees it, with summary.json on a full disk
        def __getattr__(self, name):
            return getattr(os, name)

        @staticmethod
        def replace(source, target):
            if Path(target).name == "summary.json":
                raise OSError(errno.ENOSPC, "No space left on device")
            os.replace(source, target)

    before = (copy / "summary.json").read_bytes()
    monkeypatch.setattr(files, "os", FullDisk())
    argv = ["--resume", str(copy), "--progress", "false", "--evaluate", "false"]
    code = run_cli(train_cli.main, train_cli.PROG, [*argv, "--plots", "false"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"cannot write {str(copy / 'summary.json')!r}: No space left on device" in err
    assert (copy / "summary.json").read_bytes() == before
    assert not [n for n in compiled if n in ("jit(run)", "jit(init)", "jit(evaluate)")]


FULL_DISK = r"""
import errno, os, sys
from pathlib import Path
from mara_mjx.cli import train
from mara_mjx.runtime import distributed, files

class FullDisk:  # os, as mara_mjx.runtime.files sees it, with no room for a checkpoint
    def __getattr__(self, name):
        return getattr(os, name)

    @staticmethod
    def replace(source, target):
        if Path(target).suffix == ".npz":
            raise OSError(errno.ENOSPC, "No space left on device")
        os.replace(source, target)

files.os = FullDisk()
sys.exit(distributed.run_cli(train.main, train.PROG, sys.argv[1:]))
"""


def test_a_full_disk_while_checkpointing_is_one_line_and_keeps_the_run(trained, cli_env, tmp_path):
    """Issue 34 item 12: ENOSPC (injected) writing a checkpoint: one line naming the file
    and how to continue, exit status 2, the earlier checkpoint intact, no temporary left."""
    out, _ = trained
    copy = tmp_path / "full"
    shutil.copytree(out, copy)
    (copy / CKPT2).unlink()
    args = ["--resume", str(copy), "--progress", "false", "--evaluate", "false"]
    proc = subprocess.run([sys.executable, "-c", FULL_DISK, *args], cwd=REPO, env=cli_env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert f"cannot write {str(copy / CKPT2)!r}: No space left on device" in last, last
    assert f"--resume {copy} continues the run" in last
    assert ckpt.load_checkpoint(copy / CKPT1)[1]["progress"]["update"] == 1
    assert not (copy / CKPT2).exists()
    assert not [p for p in copy.rglob("*") if p.name.endswith(".tmp") or p.name == outputs.LOCK]


# ------------------------------------------- a population, the Orient tasks' default


def test_population_run_trains_checkpoints_and_evaluates(cli_env, tmp_path):
    """`--population 2` through the CLIs, with the CLI's own preset for MARA (ik_finish:
    the IK step in the vmapped program, which deadlocked XLA:CPU before NOTES section
    30): member 0's policy in the checkpoints, which `evaluate` reads like any run's."""
    out = tmp_path / "run"
    args = [*TINY, "--population", "2", "--tensorboard", "false", "--out", str(out)]
    proc = run_module(cli_env, "mara_mjx.train", *args)
    assert proc.returncode == 0, proc.stderr[-4000:]
    config = json.loads((out / "config.json").read_text())
    assert config["curriculum"]["population"] == 2
    arrays, _ = ckpt.load_checkpoint(out / CKPT2)
    assert arrays["params/params/log_std"].shape == (2, 6)  # both members saved
    assert arrays["fitness"].shape == (2,)
    report = tmp_path / "eval.json"
    proc = run_module(cli_env, "mara_mjx.evaluate", str(out), "--json", str(report))
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert json.loads(report.read_text())


def test_orient_task_default_trains_and_its_checkpoint_runs_without_the_training_rules(
    cli_env, tmp_path, capsys, compiled
):
    """A fixed Orient task with no --preset (orient_first) through the CLIs: the run records
    the training-only rules (the roll gate, the loose standoff), `evaluate` reads the
    checkpoint, the policy a user loads from it runs without them, and `export` refuses
    it with the way out (--preset default) named, writing nothing."""
    from mara_mjx.ppo.policy import make_policy

    out = tmp_path / "run"
    tiny = [*TINY[2:], "--env", "MARAOrient", "--tensorboard", "false"]
    tiny += ["--probe_reach_steps", "5"]  # the Orient tasks' time to accuracy
    # `evaluate` below evaluates the checkpoint: the run's own final evaluation (another
    # program to compile) and its plots are not under test here
    tiny += ["--evaluate", "false", "--plots", "false"]
    proc = run_module(cli_env, "mara_mjx.train", *tiny, "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-4000:]
    saved = json.loads((out / "config.json").read_text())
    ppo = {**saved["policy"], **saved["curriculum"]}  # the sections the fields moved to
    assert ppo["ik_orient_first"] and ppo["train_ik_gate_roll"] and ppo["stagger_episodes"]
    assert ppo["train_ik_orient_loose"] and ppo["probe_reach_steps"] == 5
    # deployed: the plan and its restarts (benchmarks/NOTES.md section 60), which
    # `evaluate` below runs as the checkpoint's own rules
    assert (ppo["plan_steps"], ppo["plan_starts"]) == (16, 16)
    rows = read_rows(out / "progress.csv")  # one update per call: every row probed
    assert rows and all(float(r["reach_error_mm"]) > 0.0 for r in rows), rows
    report = tmp_path / "eval.json"
    proc = run_module(cli_env, "mara_mjx.evaluate", str(out), "--json", str(report))
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert json.loads(report.read_text())
    policy = make_policy(str(out / CKPT2))
    assert policy.config.policy.train_ik_gate_roll and not policy.network.ik_gate_roll
    assert policy.config.policy.train_ik_orient_loose and not policy.network.ik_orient_loose
    exported = tmp_path / "policy.npz"  # in-process: the refusal compiles nothing
    capsys.readouterr()
    compiled.clear()
    assert run_cli(export_cli.main, export_cli.PROG, [str(out), str(exported)]) == 2
    assert "--preset default" in capsys.readouterr().err
    assert not exported.exists()
    assert not compiled, compiled


def test_a_source_copy_without_git_still_names_its_version_and_commit(monkeypatch, tmp_path):
    """A copy of the source tree on PYTHONPATH (a GPU machine's): no installed metadata and
    no .git (or a stale one), yet an artefact records mara_mjx's version and, where the
    driver exports MARA_MJX_GIT_COMMIT, that commit."""
    from importlib import metadata

    import mara_mjx
    from mara_mjx.runtime import runs

    root = Path(runs.__file__).resolve().parents[2]
    monkeypatch.delenv(runs.GIT_COMMIT_ENV, raising=False)
    if (root / ".git").exists():  # this checkout (a clone, as CI's): its HEAD is recorded
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True,
                              text=True).stdout.strip()  # fmt: skip
        assert runs.git_commit().removesuffix("+dirty") == head
        # ... unless the driver names the commit sent: a device copy's .git can be older
        # than its tree (NOTES section 45: every run there read as the session's first HEAD)
        monkeypatch.setenv(runs.GIT_COMMIT_ENV, "0123abc")
        assert runs.git_commit() == "0123abc"

    real = metadata.version

    def version(name):
        if name == "mara_mjx":
            raise metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(runs.metadata, "version", version)
    assert runs.versions()["mara_mjx"] == mara_mjx.__version__
    (tmp_path / "pyproject.toml").touch()  # a source copy: the tree, but no .git
    monkeypatch.setattr(runs, "__file__", str(tmp_path / "mara_mjx" / "runtime" / "runs.py"))
    monkeypatch.delenv(runs.GIT_COMMIT_ENV, raising=False)
    assert runs.git_commit() is None
    monkeypatch.setenv(runs.GIT_COMMIT_ENV, "0123abc")
    assert runs.git_commit() == "0123abc"
