"""Interrupting the train CLI as a user does (Ctrl-C during the first compile and
mid-training, a killed process), then resuming or starting over: subprocesses on tiny
settings (tests/test_train_cli.py's TINY with 200 updates).

A file of its own so that it runs beside test_train_cli.py (pytest-xdist, one file per
worker); its subprocesses share a persistent compilation cache (`cli_env`).
"""

from __future__ import annotations

import os
import signal
import subprocess

from test_train_cli import TINY, read_rows, run_module, start_module

from mara_mjx.ppo import checkpoint as ckpt


def _start_train(env: dict[str, str], *args: str) -> subprocess.Popen:
    return start_module(env, "mara_mjx.train", *args)


def _wait_for(predicate, proc: subprocess.Popen, timeout: float = 300.0) -> None:
    import time

    deadline = time.monotonic() + timeout
    while not predicate():
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


# TINY with 200 updates and no periodic checkpoint
LONG = [*TINY, "--total_timesteps", "6400", "--checkpoint_every", "1000"]
QUIET = ["--progress", "false", "--tensorboard", "false", "--evaluate", "false"]


def test_ctrl_c_mid_training_writes_a_checkpoint_and_resumes(cli_env, tmp_path):
    """200 updates, checkpoint_every 1000: Ctrl-C after a few updates must still leave a
    checkpoint of the last completed update, and --resume must finish the run with each
    update logged once."""
    out = tmp_path / "run"
    proc = _start_train(cli_env, *LONG, *QUIET, "--plots", "false", "--out", str(out))
    csv_path = out / "progress.csv"
    _wait_for(lambda: csv_path.exists() and len(read_rows(csv_path)) >= 3, proc)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "--resume" in err
    (newest,) = ckpt.list_checkpoints(out)
    _, meta = ckpt.load_checkpoint(newest)
    done = meta["progress"]["update"]
    assert 3 <= done < 200
    assert [int(r["update"]) for r in read_rows(csv_path)] == list(range(1, done + 1))

    resumed = run_module(cli_env, "mara_mjx.train", "--resume", str(out), *QUIET)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert [int(r["update"]) for r in read_rows(csv_path)] == list(range(1, 201))


def test_run_stopped_before_its_first_checkpoint_can_start_over(cli_env, tmp_path):
    """Ctrl-C around the first compile writes a checkpoint (of the first call's updates,
    or of the initial state if the call had not started) that --resume continues; a run
    killed before any checkpoint can be started again with the same command, and --resume
    on it says so."""
    out = tmp_path / "run"
    args = [*LONG, *QUIET, "--plots", "false", "--out", str(out)]
    proc = _start_train(cli_env, *args)
    for line in proc.stdout:  # printed just before the first call, which compiles
        if "the first call compiles" in line:
            break
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err
    assert ckpt.list_checkpoints(out), err[-3000:]
    resumed = run_module(cli_env, "mara_mjx.train", "--resume", str(out), *QUIET)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert [int(r["update"]) for r in read_rows(out / "progress.csv")] == list(range(1, 201))

    killed = tmp_path / "killed"
    proc = _start_train(cli_env, *[a if a != str(out) else str(killed) for a in args])
    _wait_for(lambda: (killed / "progress.csv").exists(), proc)
    proc.kill()  # no handler runs: nothing is checkpointed
    proc.communicate()
    assert not ckpt.list_checkpoints(killed)
    again = run_module(cli_env, "mara_mjx.train", "--resume", str(killed))
    assert again.returncode == 2 and "same --out" in again.stderr, again.stderr[-2000:]
    restarted = run_module(cli_env, "mara_mjx.train", *args[: args.index("--out")],
                           "--out", str(killed))  # fmt: skip
    assert restarted.returncode == 0, restarted.stderr[-3000:]
    assert "starting over" in restarted.stdout
    assert [int(r["update"]) for r in read_rows(killed / "progress.csv")] == list(range(1, 201))


def test_sigterm_stops_like_ctrl_c_and_a_second_train_on_the_folder_is_refused(
    cli_env, tmp_path, capsys
):
    """A scheduler's stop (SIGTERM) writes a checkpoint and exits 143 (128 + 15, as a
    shell reports it), with the --resume line; while the run holds its folder, a second
    train with the same --out stops with a one-line error (it used to interleave both runs'
    rows and replace the other's checkpoints). The first run is frozen (SIGSTOP) while the
    second one tries, so that the test does not depend on timing."""
    from mara_mjx.cli import train as train_cli
    from mara_mjx.cli.common import run_cli

    out = tmp_path / "run"
    proc = _start_train(cli_env, *LONG, *QUIET, "--plots", "false", "--out", str(out))
    for line in proc.stdout:  # printed just before the first call, which compiles
        if "the first call compiles" in line:
            break
    # the training process: the child of the CLI's watching parent (runtime/supervise.py)
    with open(f"/proc/{proc.pid}/task/{proc.pid}/children") as f:
        trainer = int((f.read().split() or [proc.pid])[0])  # (MARA_MJX_SUPERVISE=0: itself)
    os.kill(trainer, signal.SIGSTOP)
    try:
        code = run_cli(train_cli.main, train_cli.PROG, [*LONG, *QUIET, "--out", str(out)])
        err = capsys.readouterr().err
        assert code == 2 and f"in use by another mara_mjx process (pid {trainer})" in err, err
        proc.send_signal(signal.SIGTERM)  # the parent forwards it
    finally:
        os.kill(trainer, signal.SIGCONT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err[-3000:]
    assert "SIGTERM: stopping after the jitted call in flight" in err, err[-3000:]
    assert "Traceback" not in err and f"--resume {out}" in err
    (newest,) = ckpt.list_checkpoints(out)
    done = ckpt.load_checkpoint(newest)[1]["progress"]["update"]
    assert done < 200
    assert [int(r["update"]) for r in read_rows(out / "progress.csv")] == list(range(1, done + 1))
    assert not (out / ".lock").exists()  # released on the way out
