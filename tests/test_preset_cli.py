"""A population run and the Orient tasks' default preset end to end through the CLIs, as
a user runs them (subprocesses, tiny settings). Apart from tests/test_seeds_cli.py so that
the two files' subprocess trainings run on different workers."""

from __future__ import annotations

import json

from test_train_cli import CKPT2, TINY, read_rows, run_module

from mara_mjx.ppo import checkpoint as ckpt


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
    cli_env, tmp_path
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
    rows = read_rows(out / "progress.csv")  # one update per call: every row probed
    assert rows and all(float(r["reach_error_mm"]) > 0.0 for r in rows), rows
    report = tmp_path / "eval.json"
    proc = run_module(cli_env, "mara_mjx.evaluate", str(out), "--json", str(report))
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert json.loads(report.read_text())
    policy = make_policy(str(out / CKPT2))
    assert policy.config.policy.train_ik_gate_roll and not policy.network.ik_gate_roll
    assert policy.config.policy.train_ik_orient_loose and not policy.network.ik_orient_loose
    exported = tmp_path / "policy.npz"
    proc = run_module(cli_env, "mara_mjx.export", str(out), str(exported))
    assert proc.returncode != 0 and "--preset default" in proc.stderr, proc.stderr[-2000:]
    assert not exported.exists()
