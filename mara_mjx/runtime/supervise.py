"""A watching parent for the CLIs: a run that dies in native code ends with one line.

Some failures kill a CLI before any Python code can run: XLA aborts the process (SIGABRT)
when the coordinator (process 0) of a multi-process run dies ("Terminating process
because the JAX distributed service detected fatal errors ..."), LLVM aborts when a
compile runs out of memory ("LLVM ERROR: Unable to allocate section memory",
std::bad_alloc), the kernel's out-of-memory killer sends SIGKILL. What the user saw was
a C++ stack trace, or nothing, and exit status 134 or 137. So `run` forks the CLI, once
its modules are imported and before JAX starts a backend (a fork costs ~10 ms; a re-exec
would cost Python's and JAX's import time again, ~2 s). The child runs the command as
before; this process, the parent, only watches it:

* the child's stderr passes through the parent, as it is written (a pseudo-terminal
  when stderr is one, so progress bars and colours stay as they were), and the parent
  keeps its last 8 KiB;
* when the child dies by a signal (SIGABRT, SIGSEGV, SIGKILL, ...), the parent prints one
  line that says what happened, judged from those last lines (a peer process died, out
  of memory, or a crash in native code), and exits with status 1 (a peer or memory, as
  the CLIs' own messages for them) or 128 + the signal. Every other exit status (0, 1,
  2 for user errors, 130/143 after Ctrl-C/SIGTERM) passes through unchanged, and a child
  killed by SIGINT, SIGTERM or SIGHUP kills the parent with the same signal;
* SIGINT, SIGTERM and SIGHUP sent to the parent alone (`kill PID`, `docker stop`,
  `Popen.terminate`) are forwarded to the child, once. Those that reach the child
  directly too (Ctrl-C at a terminal, which signals the whole process group; a
  scheduler or `kill -- -PGID` signalling every process) are not: a second one would
  mean "stop at once" to the train CLI. The child reports each signal it receives on a
  pipe (Python's signal wakeup fd, written by the C-level handler at once, even while
  the main thread is inside a jitted call), and the parent forwards a signal only when
  the child did not report it within 0.2 s;
* the child dies with the parent (Linux: PR_SET_PDEATHSIG; elsewhere a thread polls
  os.getppid()), so a parent killed with SIGKILL leaves no orphan holding a GPU.

MARA_MJX_SUPERVISE=0 runs the command in this process, unwatched, as does a platform
without os.fork or a process that already runs Python threads (a fork would copy their
locks, held).
"""

from __future__ import annotations

import collections
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable

ENV_VAR = "MARA_MJX_SUPERVISE"
TAIL_BYTES = 8192
GRACE_S = 0.2  # how long the child has to report a signal it got directly
FORWARD = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
WATCHED = {*FORWARD, signal.SIGCHLD, signal.SIGWINCH}
CRASHES = {"SIGABRT", "SIGSEGV", "SIGBUS", "SIGILL", "SIGFPE", "SIGKILL", "SIGSYS", "SIGTRAP"}
SI_KERNEL = 0x80  # siginfo.si_code of a signal the kernel sent (a terminal's Ctrl-C)
PR_SET_PDEATHSIG = 1

# What the child's last stderr lines say about why it aborted (JAX, XLA, LLVM, libstdc++)
_PEER = re.compile(
    r"JAX distributed service detected fatal errors|another task died|coordination service",
    re.I,
)
_COORDINATOR = re.compile(r"leader task|Failed to send RPC to coordination service", re.I)
_MEMORY = re.compile(
    r"bad_alloc|out of memory|RESOURCE_EXHAUSTED|Cannot allocate memory|"
    r"Unable to allocate|failed to allocate",
    re.I,
)


def run(command: Callable[[], int], prog: str) -> int:
    """command() in a forked child watched by this process (module docstring). The child
    returns command()'s exit status, so that it exits (atexit, buffers) exactly as an
    unwatched CLI does; this process exits with the status `_watch` gives."""
    if not _can_fork():
        return command()
    tty = os.isatty(2)
    if tty:  # the child's stderr stays a terminal
        read_end, write_end = os.openpty()
        _raw_output(write_end)
        _copy_window_size(write_end)
    else:
        read_end, write_end = os.pipe()
    wake_read, wake_write = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    parent = os.getpid()
    # Blocked before the fork: a signal that comes while the parent is still starting to
    # watch waits for `_watch` instead of killing the parent (and, with it, the child)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, WATCHED)
    pid = os.fork()
    if pid == 0:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # the command sees what it did
        os.close(read_end)
        os.close(wake_read)
        os.dup2(write_end, 2)
        os.close(write_end)
        os.set_blocking(wake_write, False)
        signal.set_wakeup_fd(wake_write, warn_on_full_buffer=False)
        _die_with(parent)
        return command()
    os.close(write_end)
    os.close(wake_write)
    code = _watch(pid, read_end, wake_read, prog, read_end if tty else None)
    os._exit(code)  # (this process did nothing else: no exit handlers to run)


def _can_fork() -> bool:
    return (
        os.environ.get(ENV_VAR, "1") != "0"
        and hasattr(os, "fork")
        and hasattr(signal, "sigtimedwait")
        and threading.active_count() == 1
        and threading.current_thread() is threading.main_thread()
    )


def _raw_output(fd: int) -> None:
    """No output processing on the pseudo-terminal ("\\n" stays "\\n"; the real terminal
    translates it)."""
    import termios

    attrs = termios.tcgetattr(fd)
    attrs[1] &= ~termios.OPOST
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


def _copy_window_size(fd: int) -> None:
    import fcntl
    import termios

    try:
        size = fcntl.ioctl(2, termios.TIOCGWINSZ, b"\0" * 8)
        fcntl.ioctl(fd, termios.TIOCSWINSZ, size)
    except OSError:
        pass


def _die_with(parent: int) -> None:
    """SIGKILL this (child) process when `parent` dies."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl")
    except (OSError, AttributeError):  # not Linux: poll

        def poll() -> None:
            while os.getppid() == parent:
                time.sleep(1.0)
            os.kill(os.getpid(), signal.SIGKILL)

        threading.Thread(target=poll, name="mara_mjx-parent", daemon=True).start()
    if os.getppid() != parent:  # it died before the prctl
        os.kill(os.getpid(), signal.SIGKILL)


class _Tail(threading.Thread):
    """Copies the child's stderr to ours as it comes, keeping the last TAIL_BYTES."""

    def __init__(self, fd: int):
        super().__init__(name="mara_mjx-stderr", daemon=True)
        self.fd, self.tail = fd, bytearray()

    def run(self) -> None:
        while True:
            try:
                data = os.read(self.fd, 65536)
            except OSError:  # EIO: a pseudo-terminal whose child side closed
                return
            if not data:
                return
            self.tail += data
            del self.tail[:-TAIL_BYTES]
            try:
                while data:
                    data = data[os.write(2, data) :]
            except OSError:
                pass  # our stderr is gone: keep draining the child's

    def text(self) -> str:
        return bytes(self.tail).decode(errors="replace")


def _watch(pid: int, output: int, wake: int, prog: str, pty: int | None) -> int:
    import gc

    gc.freeze()  # the child's pages stay shared: no collection touches them here
    # (WATCHED is blocked since the fork; the copying thread inherits the mask)
    tail = _Tail(output)
    tail.start()
    os.set_blocking(wake, False)
    got: dict[int, collections.deque] = {s: collections.deque() for s in FORWARD}
    expected: dict[int, collections.deque] = {s: collections.deque() for s in FORWARD}
    pending: list[tuple[int, float, bool]] = []  # (signal, time, from the kernel)
    while True:
        info = signal.sigtimedwait(WATCHED, 0.05 if pending else 0.5)
        now = time.monotonic()
        try:
            reported = os.read(wake, 4096)
        except (BlockingIOError, OSError):
            reported = b""
        for s in FORWARD:
            while expected[s] and now - expected[s][0] > 2.0:
                expected[s].popleft()
        for s in reported:  # the child's signals: ours (expected) or its own
            if s in got:
                if expected[s]:
                    expected[s].popleft()
                else:
                    got[s].append(now)
        if info is not None:
            if info.si_signo in FORWARD:
                pending.append((info.si_signo, now, info.si_code == SI_KERNEL))
            elif info.si_signo == signal.SIGWINCH and pty is not None:
                _copy_window_size(pty)
        for item in list(pending):
            s, at, kernel = item
            while got[s] and got[s][0] < at - 1.0:
                got[s].popleft()
            if got[s]:  # the child got this one itself
                got[s].popleft()
            elif kernel:  # sent to the whole group: the child's report is still to come
                expected[s].append(now)
            elif now - at >= GRACE_S:
                expected[s].append(now)
                os.kill(pid, s)
            else:
                continue
            pending.remove(item)
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
    tail.join(timeout=2.0)  # the child's own children may keep its stderr open
    code = os.waitstatus_to_exitcode(status)
    if code >= 0:
        return code
    signum = -code
    message, code = explain(signum, tail.text(), prog)
    if message is None:  # a stop signal: end as the child did
        signal.signal(signum, signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signum})
        os.kill(os.getpid(), signum)
        return code
    os.write(2, f"{message}\n".encode())
    return code


def explain(signum: int, tail: str, prog: str) -> tuple[str | None, int]:
    """The line to print (None: nothing) and the exit status for a child killed by
    `signum` whose stderr ended with `tail`."""
    name = signal.Signals(signum).name
    if name not in CRASHES:
        return None, 128 + signum
    lines = [line.strip() for line in tail.splitlines() if line.strip()]
    peer = next((line for line in reversed(lines) if _PEER.search(line)), None)
    if peer is not None:
        where = _coordinator()
        who = (
            f"process 0 (the coordinator{f', at {where}' if where else ''})"
            if _COORDINATOR.search(tail)
            else "another process of this multi-process run"
        )
        return (
            f"{prog}: error: JAX ended this process ({name}) because {who} died, was "
            "killed or cannot be reached; that process's output says why. Start every "
            "process again; --resume RUN_FOLDER continues from the last checkpoint",
            1,
        )
    memory = next((line for line in reversed(lines) if _MEMORY.search(line)), None)
    if memory is not None:
        return (
            f"{prog}: error: out of memory ({name} in native code, e.g. while compiling: "
            f"{_short(memory)}); fewer --num_envs, --num_steps or --episodes need less",
            1,
        )
    if name == "SIGKILL":
        return (
            f"{prog}: error: the process was killed (SIGKILL): by a user, a scheduler's "
            "limit or the system's out-of-memory killer (`dmesg` or `journalctl -k` says "
            "which); fewer --num_envs, --num_steps or --episodes need less memory",
            128 + signum,
        )
    return (
        f"{prog}: error: the process crashed ({name}) in native code (JAX, XLA, MuJoCo); "
        "the lines above say where",
        128 + signum,
    )


def _coordinator() -> str | None:
    """The --coordinator of the command line, else MARA_COORDINATOR's."""
    argv = sys.argv
    for i, arg in enumerate(argv):
        if arg == "--coordinator" and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("--coordinator="):
            return arg.split("=", 1)[1]
    return os.environ.get("MARA_COORDINATOR") or None


def _short(line: str, limit: int = 160) -> str:
    return line if len(line) <= limit else line[: limit - 3] + "..."
