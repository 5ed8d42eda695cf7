"""The CLIs' watching parent (mara_mjx/runtime/supervise.py): a child that aborts in native
code ends with one clear line, exit statuses and signals pass through once, and the child
dies with its parent. Small subprocesses that import no JAX (a fraction of a second each);
the real 2-process case (process 0 killed) is in test_distributed.py."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mara_mjx.runtime import supervise

REPO = Path(__file__).resolve().parents[1]

# argv[1]: what the watched command does; argv[2]: supervise.py, loaded alone (importing
# mara_mjx would import JAX: 1.5 s a process)
CHILD = r"""
import importlib.util, os, signal, sys, time
signal.signal(signal.SIGHUP, signal.SIG_DFL)  # not ignored as under nohup: a user's default
spec = importlib.util.spec_from_file_location("supervise", sys.argv[2])
supervise = importlib.util.module_from_spec(spec)
spec.loader.exec_module(supervise)
if len(sys.argv) > 3:  # a parent slow to start watching (a loaded machine): argv[3] seconds
    watch = supervise._watch
    supervise._watch = lambda *a: (time.sleep(float(sys.argv[3])), watch(*a))[1]

def command():
    what = sys.argv[1]
    if what == "peer":  # JAX's words (jax 0.10.2) when process 0 dies
        print("F1127 client.h:80] Terminating process because the JAX distributed service "
              "detected fatal errors. This most likely indicates that another task died; "
              "absl::Status: UNAVAILABLE: Failed to send RPC to coordination service. Either "
              "the leader task was preempted/died/restarted unexpectedly", file=sys.stderr)
        os.abort()
    if what == "llvm":  # a compile out of memory (benchmarks/NOTES.md section 31)
        print("LLVM ERROR: Unable to allocate section memory!", file=sys.stderr)
        os.abort()
    if what == "segv":
        os.kill(os.getpid(), signal.SIGSEGV)
    if what.isdigit():
        print("to stderr", file=sys.stderr)
        return int(what)
    if what == "raise":
        raise ValueError("a bug")
    # "stop": count the SIGTERMs, as the train CLI's StopRequest does (the second means
    # "stop at once"), then exit 143
    seen = []
    signal.signal(signal.SIGTERM, lambda *a: seen.append(1))
    print(os.getpid(), flush=True)
    deadline = time.monotonic() + 20
    while not seen and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.5)  # a second signal would come in this time
    print(f"SIGTERMs: {len(seen)}", file=sys.stderr)
    return 143

sys.exit(supervise.run(command, "prog"))
"""


def start(what: str, *extra: str, **kwargs) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if k != supervise.ENV_VAR}
    return subprocess.Popen(
        [sys.executable, "-c", CHILD, what, supervise.__file__, *extra],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


def finish(proc: subprocess.Popen) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=30)
    return proc.returncode, out, err


def test_an_abort_in_native_code_ends_with_one_clear_line():
    start_time = time.monotonic()
    peer, llvm, segv = (start(w) for w in ("peer", "llvm", "segv"))
    code, _, err = finish(peer)
    assert code == 1, err  # (unwatched: -6, SIGABRT, and a C++ stack)
    assert "Terminating process because" in err  # JAX's own lines pass through
    last = err.strip().splitlines()[-1]
    assert last.startswith("prog: error: JAX ended this process (SIGABRT) because process 0")
    assert "--resume" in last
    code, _, err = finish(llvm)
    assert code == 1, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("prog: error: out of memory (SIGABRT in native code"), last
    assert "LLVM ERROR: Unable to allocate section memory" in last
    code, _, err = finish(segv)
    assert code == 128 + signal.SIGSEGV, err
    assert err.strip().splitlines()[-1].startswith("prog: error: the process crashed (SIGSEGV)")
    assert time.monotonic() - start_time < 15


def test_exit_statuses_pass_through():
    for code in (0, 2, 130):
        got, _, err = finish(start(str(code)))
        assert (got, err) == (code, "to stderr\n")
    got, _, err = finish(start("raise"))
    assert got == 1 and "ValueError: a bug" in err and "prog: error" not in err


def wait_line(proc: subprocess.Popen) -> int:
    return int(proc.stdout.readline())


def test_sigterm_reaches_the_child_once():
    """SIGTERM to the parent alone is forwarded; SIGTERM to the whole process group (a
    scheduler's stop) reaches the child directly and is not forwarded as a second one."""
    alone = start("stop")
    group = start("stop", start_new_session=True)
    wait_line(alone), wait_line(group)
    alone.send_signal(signal.SIGTERM)
    os.killpg(group.pid, signal.SIGTERM)
    for proc in (alone, group):
        code, _, err = finish(proc)
        assert code == 143 and "SIGTERMs: 1" in err, (code, err)


def test_a_signal_before_the_parent_watches_waits_for_it():
    """A SIGTERM that comes between the fork and the parent's first look (CI's loaded
    machine once: the parent died of it, and the child with it) is held, then forwarded."""
    alone = start("stop", "1.0")
    group = start("stop", "1.0", start_new_session=True)
    wait_line(alone), wait_line(group)  # the children run; both parents still sleep
    alone.send_signal(signal.SIGTERM)
    os.killpg(group.pid, signal.SIGTERM)
    for proc in (alone, group):
        code, _, err = finish(proc)
        assert code == 143 and "SIGTERMs: 1" in err, (code, err)


def test_a_child_killed_by_a_stop_signal_ends_its_parent_alike():
    proc = start("stop")
    child = wait_line(proc)
    os.kill(child, signal.SIGKILL)
    code, _, err = finish(proc)
    assert code == 128 + signal.SIGKILL and "killed (SIGKILL)" in err  # (the OOM killer's)
    proc = start("stop")
    child = wait_line(proc)
    os.kill(child, signal.SIGHUP)  # no handler: the child dies of it, and so does the parent
    code, _, err = finish(proc)
    assert code == -signal.SIGHUP and "prog: error" not in err, (code, err)


def dead(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc")
def test_the_child_dies_with_its_parent():
    proc = start("stop")
    child = wait_line(proc)
    proc.kill()
    proc.communicate(timeout=30)
    deadline = time.monotonic() + 5
    while not dead(child):
        assert time.monotonic() < deadline, "the child outlived its parent"
        time.sleep(0.02)


def test_explain():
    abort, kill = signal.SIGABRT, signal.SIGKILL
    assert supervise.explain(signal.SIGTERM, "", "p") == (None, 143)
    assert supervise.explain(signal.SIGINT, "", "p") == (None, 130)
    peer = "E coordination_service_agent.cc Polled an error from coordination service"
    message, code = supervise.explain(abort, peer, "p")
    assert code == 1 and "another process of this multi-process run" in message
    message, code = supervise.explain(kill, "std::bad_alloc", "p")
    assert code == 1 and message.startswith("p: error: out of memory (SIGKILL")
    message, code = supervise.explain(kill, "", "p")
    assert code == 137 and "out-of-memory killer" in message
