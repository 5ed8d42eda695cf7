"""Nothing a user does loses their work (issue 34): every output a user names is checked
before anything runs, `--out` is a new folder or a mara_mjx run's, a run folder is one
run's and written by one process at a time, and what a killed writer leaves is cleaned.

The runs here are built without training (test_export_plots.make_run: a real checkpoint
of random params, plus the config.json the train CLI writes), and every case fails before
anything is compiled. The cases that need a trained run are in test_train_cli.py; the
signals (SIGTERM, a second train on a running run's folder) in test_interrupt.py.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_export_plots import make_run

from mara_mjx.bench import runner
from mara_mjx.cli import evaluate as evaluate_cli
from mara_mjx.cli import export
from mara_mjx.cli import train as train_cli
from mara_mjx.cli.common import UserError, run_cli
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo import logger
from mara_mjx.runtime import files, outputs, runs

REPO = Path(__file__).resolve().parents[1]


def fake_run(folder: Path, env_name: str = "MARA", seed: int = 0, **ppo) -> Path:
    """A run folder as the train CLI leaves it (config.json, progress.csv, one
    checkpoint), of an untrained policy (`seed`: its params'; `ppo`: PPOConfig fields);
    returns the checkpoint."""
    path = make_run(folder, env_name, True, seed=seed, **ppo)
    _, meta = ckpt.load_checkpoint(path)
    runs.write_json(folder / "config.json", {**meta, "resume_from": None})
    (folder / "progress.csv").write_text("update,env_steps\n1,100\n2,200\n3,300\n")
    return path


def snapshot(*folders: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for f in folders for p in sorted(f.rglob("*")) if p.is_file()}


def one_line_error(code: int, err: str, prog: str, *expected: str) -> None:
    assert code == 2, err
    assert err.startswith(f"{prog}: error:") and len(err.strip().splitlines()) == 1, err
    for text in expected:
        assert text in err, (text, err)


# ----------------------------------------------------- outputs a user points somewhere


def test_evaluate_json_never_replaces_a_checkpoint_or_a_run_file(tmp_path, capsys):
    """Issue 34 item 1 (and item 12's --json naming a folder): refused before anything
    runs, every file as it was."""
    run, other = tmp_path / "run", tmp_path / "other"
    checkpoint = fake_run(run)
    fake_run(other, seed=1)
    (other / "eval.json").write_text('{"env_name": "MARA"}')
    moved = tmp_path / "moved.npz"  # a checkpoint outside any checkpoints/ folder
    shutil.copy(checkpoint, moved)
    notes = tmp_path / "notes.json"
    notes.write_text("the user's own file")
    (tmp_path / "folder").mkdir()
    before = snapshot(tmp_path)
    cases = [
        (checkpoint, "inside a run's checkpoints/ folder"),
        (moved, "is a training checkpoint"),
        (run / "progress.csv", "is the progress.csv of the run folder"),
        (run / "config.json", "is the config.json of the run folder"),
        (other / "eval.json", "is the eval.json of the run folder"),
        (other / ckpt.CHECKPOINT_DIR / "report.json", "inside a run's checkpoints/"),
        (notes, "pass --overwrite to replace it"),
        (tmp_path / "folder", "is a folder"),
    ]
    for target, message in cases:
        code = run_cli(evaluate_cli.main, evaluate_cli.PROG, [str(run), "--json", str(target)])
        one_line_error(code, capsys.readouterr().err, evaluate_cli.PROG, message)
    # --overwrite is for other files only: a checkpoint or a run's file stays refused
    for target in (checkpoint, run / "progress.csv"):
        argv = [str(run), "--json", str(target), "--overwrite"]
        assert run_cli(evaluate_cli.main, evaluate_cli.PROG, argv) == 2
        capsys.readouterr()
    assert snapshot(tmp_path) == before
    assert not list(tmp_path.rglob("eval-*.json"))

    # as a user runs it
    proc = subprocess.run(
        [sys.executable, "-m", "mara_mjx.evaluate", str(run), "--json", str(checkpoint)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert snapshot(tmp_path) == before


def test_what_check_output_lets_through(tmp_path):
    """A new file, an earlier report of the same command (re-running an evaluation), or
    anything else with --overwrite."""
    report = tmp_path / "eval-ckpt-train.json"
    assert outputs.check_output(report, "report", outputs.is_report) == report  # new
    runs.write_json(report, {"env_name": "MARA", "versions": {}, "episodes": []})
    assert outputs.check_output(report, "report", outputs.is_report) == report  # an earlier one
    md = report.with_suffix(".md")
    md.write_text("| table |")
    assert outputs.check_output(md, "markdown", outputs.companion_of(report)) == md
    foreign = tmp_path / "data.json"
    foreign.write_text('{"mine": 1}')
    with pytest.raises(UserError, match="--overwrite"):
        outputs.check_output(foreign, "report", outputs.is_report)
    assert outputs.check_output(foreign, "report", outputs.is_report, overwrite=True) == foreign


def test_evaluate_of_a_seeds_run_never_replaces_a_seeds_checkpoint(tmp_path, capsys):
    top = tmp_path / "seeds"
    for s in (0, 1):
        fake_run(top / f"seed_{s}", seed=s)
    runs.write_json(top / "seeds.json", {"env_name": "MARA", "seeds": [0, 1]})
    seed1 = ckpt.list_checkpoints(top / "seed_1")[-1]
    before = snapshot(tmp_path)
    cases = [
        (seed1, "inside a run's checkpoints/"),
        (top / "seeds.json", "is the seeds.json of the multi-seed run folder"),
        (top / "seed_0" / "progress.csv", "is the progress.csv of the run folder"),
    ]
    for target, message in cases:
        code = run_cli(evaluate_cli.main, evaluate_cli.PROG, [str(top), "--json", str(target)])
        one_line_error(code, capsys.readouterr().err, evaluate_cli.PROG, message)
    assert snapshot(tmp_path) == before


def test_export_and_benchmark_refuse_files_they_did_not_write(tmp_path, capsys):
    run = tmp_path / "run"
    fake_run(run)
    foreign = tmp_path / "data.npz"
    np.savez(foreign, x=np.arange(3))
    before = foreign.read_bytes()
    code = run_cli(export.main, "export", [str(run), str(foreign)])
    one_line_error(code, capsys.readouterr().err, "export", "pass --overwrite")
    assert foreign.read_bytes() == before
    assert run_cli(export.main, "export", [str(run), str(foreign), "--overwrite"]) == 0
    assert export.load_exported(foreign).env_name == "MARA"
    capsys.readouterr()

    parser = runner.build_parser("")
    out = tmp_path / "bench"
    out.mkdir()
    (out / "env.md").write_text("the user's notes")
    with pytest.raises(SystemExit) as refused:
        runner.resolve(parser, ["env", "--out", str(out)])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and "env.md" in err and "--overwrite" in err, err
    assert (out / "env.md").read_text() == "the user's notes"
    assert runner.resolve(parser, ["env", "--out", str(out), "--overwrite"]).overwrite
    (out / "env.md").unlink()
    runs.write_json(out / "env.json", {"study": "env", "records": [], "config": {}})
    (out / "env.md").write_text("| an earlier table |")  # the study's own: replaced
    assert runner.resolve(parser, ["env", "--out", str(out)]).out == str(out)
    with pytest.raises(SystemExit):  # a checkpoints/ folder is never a results folder
        runner.resolve(parser, ["env", "--out", str(run / ckpt.CHECKPOINT_DIR), "--overwrite"])
    capsys.readouterr()


# ----------------------------------------------------------------- training's --out

TINY = [
    "--env", "MARA",
    "--num_envs", "4",
    "--num_steps", "8",
    "--total_timesteps", "64",
    "--num_minibatches", "2",
]  # fmt: skip


def test_train_out_that_is_not_a_run_folder_is_refused_untouched(tmp_path, capsys):
    """Issue 34 item 4: a folder of anything else is never cleaned or written into."""
    with_csv = tmp_path / "with_csv"  # once taken for a run stopped before a checkpoint
    (with_csv / "tb").mkdir(parents=True)
    (with_csv / "progress.csv").write_text("a,b\n1,2\n")
    (with_csv / "tb" / "events.out.tfevents.1").write_text("their events")
    other = tmp_path / "other"
    other.mkdir()
    (other / "config.json").write_text('{"not": "ours"}')
    (other / "summary.json").write_text("{}")
    single = tmp_path / "single"
    fake_run(single)
    before = snapshot(tmp_path)
    for out in (with_csv, other):
        for extra in ([], ["--seeds", "2"]):
            code = run_cli(train_cli.main, train_cli.PROG, [*TINY, *extra, "--out", str(out)])
            one_line_error(
                code, capsys.readouterr().err, train_cli.PROG, "is not a mara_mjx run folder"
            )
    code = run_cli(train_cli.main, train_cli.PROG, [*TINY, "--seeds", "2", "--out", str(single)])
    one_line_error(code, capsys.readouterr().err, train_cli.PROG, "is a run of one seed")
    assert snapshot(tmp_path) == before
    assert not (with_csv / ".lock").exists() and not (with_csv / "checkpoints").exists()


HOLD = r"""
import sys, time
from mara_mjx.runtime import files
assert files.FolderLock(sys.argv[1], ".lock").acquire()
print("locked", flush=True)
time.sleep(600)
"""


def test_a_run_folder_another_process_writes_is_refused(tmp_path, capsys):
    """Issue 34 item 2 (the lock; two real train processes: test_interrupt.py)."""
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE,
                              text=True)  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "locked"
        code = run_cli(train_cli.main, train_cli.PROG, [*TINY, "--out", str(out)])
        one_line_error(
            code,
            capsys.readouterr().err,
            train_cli.PROG,
            f"is in use by another mara_mjx process (pid {holder.pid})",
        )
    finally:
        holder.kill()  # kill -9: the lock goes with it
        holder.wait()
    assert [p.name for p in out.iterdir()] == [".lock"]
    assert runs.claim_folder(out).acquire()  # not stuck


def test_taking_a_run_folder_cleans_what_a_killed_writer_left(tmp_path):
    """Issue 34 item 11: kill -9 mid-write leaves `.<name>.<hex>.tmp` files; the next
    command on the folder deletes them (only those: a user's files stay)."""
    run = tmp_path / "run"
    checkpoint = fake_run(run)
    left = [
        run / ckpt.CHECKPOINT_DIR / ".ckpt_00000004.npz.0a1b2c3d.tmp",
        run / ".config.json.00000000.tmp",
        run / ".progress.csv.ffffffff.tmp",
    ]
    kept = [run / ".notes.tmp", run / ".eval-ckpt_00000003-train.json.12345678.tmp"]
    for path in left + kept:  # (the last: another command's report, being written now)
        path.write_bytes(b"half a file")
    lock = runs.prepare_run_folder(run, checkpoint, run.resolve())
    try:
        assert not [p for p in left if p.exists()] and all(p.exists() for p in kept)
        assert (run / outputs.LOCK).read_text().strip().isdigit()
    finally:
        lock.release()
    assert not (run / outputs.LOCK).exists()

    # a run of ours stopped before its first checkpoint starts over: its events go, a
    # file of the user's in tb/ stays
    stopped = tmp_path / "stopped"
    fake_run(stopped)
    shutil.rmtree(stopped / ckpt.CHECKPOINT_DIR)
    (stopped / "tb").mkdir()
    (stopped / "tb" / "events.out.tfevents.1.host").write_text("old events")
    (stopped / "tb" / "README").write_text("mine")
    runs.prepare_run_folder(stopped, None, None).release()
    assert [p.name for p in (stopped / "tb").iterdir()] == ["README"]


def test_resume_refuses_another_runs_or_another_tasks_checkpoint(tmp_path, capsys):
    """Issue 34 item 5: `--resume` into another run's folder, or with another task's
    checkpoint placed in checkpoints/, is refused; nothing is rewritten."""
    run, other, orient = tmp_path / "run", tmp_path / "other", tmp_path / "orient"
    fake_run(run)
    fake_run(other, seed=1, learning_rate=1e-4)
    placed = make_run(orient, "MARAOrient", True)
    shutil.copy(placed, run / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(9))
    mixed = tmp_path / "mixed"
    shutil.copytree(run, mixed)
    (run / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(9)).unlink()
    before = snapshot(tmp_path)
    cases = [
        ([str(mixed)], "is MARAOrient, seed 0, the folder's config.json is MARA, seed 0"),
        ([str(run), "--out", str(other)], "they differ in ppo"),
    ]
    for argv, message in cases:
        code = run_cli(train_cli.main, train_cli.PROG, ["--resume", *argv])
        one_line_error(code, capsys.readouterr().err, train_cli.PROG, "is not of the run in",
                       message)  # fmt: skip
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize(
    "content",
    ['{"env_name": "MARA", "seeds": []}', '{"seeds": [0, 0]}', '{"seeds": [true]}',
     '{"seeds": "01"}', "[0, 1]", '{"seeds": [0, 1.5]}', "null", "{not json"],
)  # fmt: skip
def test_an_edited_seeds_json_is_a_one_line_error(tmp_path, capsys, content):
    """Issue 34 item 12."""
    top = tmp_path / "seeds"
    fake_run(top / "seed_0")
    (top / "seeds.json").write_text(content)
    for main, prog, argv in (
        (evaluate_cli.main, evaluate_cli.PROG, [str(top)]),
        (train_cli.main, train_cli.PROG, ["--resume", str(top)]),
    ):
        code = run_cli(main, prog, argv)
        one_line_error(code, capsys.readouterr().err, prog, "seeds.json")


# ----------------------------------------------------------------- progress.csv, signals


def test_resume_rewrites_progress_csv_atomically(tmp_path, monkeypatch):
    """Issue 34 item 3: an interrupt mid-rewrite leaves the whole old file (it used to
    leave it empty); the rewrite drops the rows after the checkpoint and a row cut short
    by a crash; a CSV without an `update` column is a clear error."""
    csv_path = tmp_path / "progress.csv"
    text = "update,env_steps\n1,10\n2,20\n3,30\n4,40\n5,5"  # the last row cut short
    csv_path.write_text(text)
    columns = ("update", "env_steps")

    def interrupted(self, rows):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr("csv.DictWriter.writerows", interrupted)
        with pytest.raises(KeyboardInterrupt):
            logger.RunLogger(tmp_path, columns, False, resume_update=3)
    assert csv_path.read_text() == text
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    logger.RunLogger(tmp_path, columns, False, resume_update=3).close()
    assert csv_path.read_text().split() == ["update,env_steps", "1,10", "2,20", "3,30"]
    cut = "update,env_steps\n1,10\n2,20\n3"  # killed mid-row before the checkpoint
    csv_path.write_text(cut)
    logger.RunLogger(tmp_path, columns, False, resume_update=3).close()
    assert csv_path.read_text().split() == ["update,env_steps", "1,10", "2,20"]

    csv_path.write_text("step,reward\n1,0.5\n")
    with pytest.raises(logger.ProgressError, match="has no 'update' column"):
        logger.RunLogger(tmp_path, columns, False, resume_update=1)


def test_sigterm_stops_like_ctrl_c(monkeypatch, capsys):
    """Issue 34 item 11 (the train CLI under SIGTERM: test_interrupt.py): while a
    StopRequest is active, the first SIGTERM asks to stop, the second interrupts; the
    exit status is 128 + the signal, as a shell reports it."""
    import os

    monkeypatch.setattr(runs, "_STOP_SIGNAL", [])
    stop = runs.StopRequest("stopping after the call in flight")
    with stop:
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.requested
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
    assert "SIGTERM: stopping after the call in flight" in capsys.readouterr().err
    assert runs.exit_status() == 143
    assert signal.getsignal(signal.SIGTERM) is not stop._handle  # restored
    monkeypatch.setattr(runs, "_STOP_SIGNAL", [])
    assert runs.exit_status() == 130


def test_a_full_disk_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    """Issue 34 item 12, the evaluate CLI's report on a full disk (ENOSPC injected: no
    small file system here; the evaluation itself is stubbed, it is other tests')."""
    import errno
    import os

    class FullDisk:  # os, as mara_mjx.runtime.files sees it, on a full disk
        def __getattr__(self, name):
            return getattr(os, name)

        @staticmethod
        def replace(*args):
            raise OSError(errno.ENOSPC, "No space left on device")

    class Result:
        def episodes(self):
            return []

        def summary(self):
            return {}

    run = tmp_path / "run"
    fake_run(run)
    monkeypatch.setattr(evaluate_cli, "evaluate", lambda *args, **kwargs: Result())
    monkeypatch.setattr(evaluate_cli, "format_table", lambda *args, **kwargs: "| table |")
    monkeypatch.setattr(files, "os", FullDisk())
    out = tmp_path / "report.json"
    code = run_cli(evaluate_cli.main, evaluate_cli.PROG, [str(run), "--json", str(out)])
    one_line_error(code, capsys.readouterr().err, evaluate_cli.PROG,
                   f"cannot write {str(out)!r}: No space left on device")  # fmt: skip
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.suffix == ".tmp"]

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluate_cli, "evaluate", ctrl_c)  # Ctrl-C mid-evaluation
    code = run_cli(evaluate_cli.main, evaluate_cli.PROG, [str(run), "--json", str(out)])
    err = capsys.readouterr().err
    assert code == 130 and err.strip() == "mara_mjx.evaluate: interrupted; no report was written"


# ------------------------------------------------------------------ a missing peer

PEER = r"""
import sys, time
from mara_mjx.runtime import distributed
from mara_mjx.runtime.launch import Launch


def main(argv):
    port, index, join = argv
    launch = Launch(f"localhost:{port}", 2, int(index), heartbeat_timeout=3, join_timeout=int(join))
    distributed.initialize(launch)
    print("joined", flush=True)
    time.sleep(300)
    return 0


sys.exit(distributed.run_cli(main, "mara_mjx.train", sys.argv[1:]))
"""


def _peer(port: int, index: int, join: int) -> subprocess.Popen:
    import os

    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-c", PEER, str(port), str(index), str(join)],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_a_missing_peer_ends_the_others_with_one_line(tmp_path):
    """A process that never joins, or dies once joined, ends the others within the join or
    heartbeat timeout, with one line and a non-zero status (JAX alone aborted them with a
    C++ stack trace: "Terminating process because the JAX distributed service detected
    fatal errors"). Nothing is compiled: the processes only join and wait."""
    import time

    from test_distributed import free_port

    alone = _peer(free_port(), 0, join=3)  # process 1 never starts
    port = free_port()
    killed = [_peer(port, i, join=120) for i in (0, 1)]
    try:
        _, err = alone.communicate(timeout=240)
        assert alone.returncode == 2, err[-3000:]
        assert err.strip().splitlines()[-1] == (
            f"mara_mjx.train: error: could not join the run at localhost:{alone.args[3]} as "
            "process 0 of 2: not all joined within 3 s (did every process start, with the same "
            "--coordinator and --num_processes? --join_timeout sets how long to wait)"
        ), err[-3000:]
        assert "Terminating process" not in err

        for p in killed:
            assert p.stdout.readline().strip() == "joined", p.communicate()[1][-3000:]
        killed[1].kill()
        start = time.monotonic()
        _, err = killed[0].communicate(timeout=120)
        assert killed[0].returncode == 1, err[-3000:]
        assert time.monotonic() - start < 30
        assert "Terminating process" not in err and "Traceback" not in err, err[-3000:]
        assert (
            err.strip()
            .splitlines()[-1]
            .startswith(
                "mara_mjx.train: error: process 0 of 2 failed: process 1 sent no sign of life for "
                "3 s (--heartbeat_timeout)"
            )
        ), err[-3000:]
    finally:
        for p in (alone, *killed):
            p.kill()
            p.communicate()
