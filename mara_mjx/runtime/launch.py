"""How a process joins a multi-process training run: the train CLI's launch flags, their
MARA_* environment variables and SLURM detection (`launch_from`), as a `Launch`.
`mara_mjx.runtime.distributed` starts JAX's distributed runtime from it, and then a `Watchdog`
that ends this process with one line when a peer stops beating.

    python -m mara_mjx.train ... --coordinator host0:1234 --num_processes 2 --process_id 0
    MARA_COORDINATOR=host0:1234 MARA_NUM_PROCESSES=2 MARA_PROCESS_ID=1 python -m mara_mjx.train ...
"""

from __future__ import annotations

import argparse
import atexit
import dataclasses
import os
import sys
import threading
import time
from typing import Any

from mara_mjx.cli.common import UserError

MODES = ("auto", "off")
ENV_VARS = {
    "coordinator": "MARA_COORDINATOR",
    "num_processes": "MARA_NUM_PROCESSES",
    "process_id": "MARA_PROCESS_ID",
    "distributed": "MARA_DISTRIBUTED",
    "heartbeat_timeout": "MARA_HEARTBEAT_TIMEOUT",
    "join_timeout": "MARA_JOIN_TIMEOUT",
}


class DistributedError(UserError):
    """A multi-process launch that cannot work (bad settings, a process that failed or
    disagrees): a user error (one line, exit status 2)."""


@dataclasses.dataclass(frozen=True)
class Launch:
    """How this process joins a multi-process run (None fields: JAX finds them, e.g. from
    SLURM)."""

    coordinator: str | None = None
    num_processes: int | None = None
    process_id: int | None = None
    heartbeat_timeout: int | None = None
    join_timeout: int | None = None
    source: str = "flags"
    """Where the settings came from: 'flags' (flags or MARA_* variables) or 'slurm'."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags of the module docstring, in their own group."""
    group = parser.add_argument_group(
        "several processes (jax.distributed; each flag also reads the MARA_* variable named)"
    )
    group.add_argument(
        "--coordinator",
        metavar="HOST:PORT",
        help="address of process 0, which serves the coordination there; every process "
        "gives the same (MARA_COORDINATOR)",
    )
    group.add_argument(
        "--num_processes",
        type=int,
        metavar="N",
        help="number of processes in the run (MARA_NUM_PROCESSES)",
    )
    group.add_argument(
        "--process_id",
        type=int,
        metavar="I",
        help="this process, 0..N-1; process 0 writes the run folder (MARA_PROCESS_ID)",
    )
    group.add_argument(
        "--distributed",
        choices=MODES,
        help="auto: join a multi-process run when the flags above are given or SLURM runs "
        "this as one of several tasks; off: always one process (MARA_DISTRIBUTED; "
        "default: auto)",
    )
    group.add_argument(
        "--heartbeat_timeout",
        type=int,
        metavar="SECONDS",
        help="a process that sends no sign of life for this long counts as dead and the "
        "others stop, with one line naming it (MARA_HEARTBEAT_TIMEOUT; default: 100)",
    )
    group.add_argument(
        "--join_timeout",
        type=int,
        metavar="SECONDS",
        help="how long to wait for every process to join; then every process that did stops "
        "with one line (MARA_JOIN_TIMEOUT; default: 300)",
    )


def launch_from(args: argparse.Namespace, environ: dict[str, str] | None = None) -> Launch | None:
    """The launch that flags (first) and MARA_* variables ask for; None for one process.
    DistributedError names the bad setting and the valid choices."""
    environ = os.environ if environ is None else environ

    def get(name: str, kind: type) -> Any:
        value = getattr(args, name, None)
        if value is not None:
            return value
        text = environ.get(ENV_VARS[name], "").strip()
        if not text:
            return None
        if kind is int:
            try:
                return int(text)
            except ValueError:
                raise DistributedError(f"{ENV_VARS[name]}={text!r} is not an integer") from None
        return text

    mode = get("distributed", str) or "auto"
    if mode not in MODES:
        raise DistributedError(f"distributed mode {mode!r} is invalid; choose one of {MODES}")
    coordinator = get("coordinator", str)
    num_processes = get("num_processes", int)
    process_id = get("process_id", int)
    heartbeat, join = get("heartbeat_timeout", int), get("join_timeout", int)
    for name, value in (("heartbeat_timeout", heartbeat), ("join_timeout", join)):
        if value is not None and value < 1:
            raise DistributedError(f"{name} must be >= 1 second, got {value}")
    if mode == "off":
        return None
    if coordinator is not None:
        host, _, port = coordinator.rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise DistributedError(
                f"coordinator {coordinator!r} is not HOST:PORT (e.g. localhost:12355 or "
                "node001:12355, the address of process 0)"
            )
    if num_processes is not None and num_processes < 1:
        raise DistributedError(f"num_processes must be >= 1, got {num_processes}")
    if process_id is not None:
        upper = f"0..{num_processes - 1}" if num_processes else ">= 0"
        if process_id < 0 or (num_processes is not None and process_id >= num_processes):
            raise DistributedError(f"process_id={process_id} is out of range; choose {upper}")
    given = {"coordinator": coordinator, "num_processes": num_processes, "process_id": process_id}
    slurm = _slurm_tasks(environ) > 1
    if any(v is not None for v in given.values()):
        if num_processes == 1 and coordinator is None:
            return None  # explicitly one process
        missing = [k for k, v in given.items() if v is None]
        if missing and not slurm:
            raise DistributedError(
                "several processes need --coordinator, --num_processes and --process_id "
                f"(or {', '.join(ENV_VARS[k] for k in given)}); missing: "
                f"{', '.join(missing)} (under SLURM, JAX finds what is not given)"
            )
        return Launch(coordinator, num_processes, process_id, heartbeat, join, "flags")
    if slurm:
        return Launch(None, None, None, heartbeat, join, "slurm")
    return None


def _slurm_tasks(environ: dict[str, str]) -> int:
    """The number of tasks of this SLURM job step (1 outside SLURM)."""
    if "SLURM_JOB_ID" not in environ:
        return 1
    for name in ("SLURM_STEP_NUM_TASKS", "SLURM_NTASKS"):
        text = environ.get(name, "")
        if text.isdigit():
            return int(text)
    return 1


def first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


class Watchdog:
    """A daemon thread that ends this process (one line on stderr, exit status 1) when
    another process of the run stops beating for `timeout` seconds, or the coordinator
    stops answering: every `interval` s it posts its beat count to the coordination
    service's key-value store and reads the others'. Stopped at exit, before JAX's own
    shutdown (atexit: last registered, first run), and after the run's last barrier."""

    def __init__(self, timeout: float, prog: list[str], interval: float = 1.0):
        from jax._src import distributed as jax_distributed

        state = jax_distributed.global_state  # (not jax.process_index: no backend yet)
        self.client = state.client
        self.index, self.count = state.process_id, state.num_processes or 1
        self.timeout, self.interval = float(timeout), min(interval, timeout / 4)
        self.prog = prog  # [the CLI's name in messages], set once the CLI runs
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, name="mara_mjx-watchdog", daemon=True)

    def start(self) -> bool:
        """Start watching (False, nothing started, outside a joined multi-process run)."""
        if self.client is None or self.count < 2:
            return False
        atexit.register(self.stop)
        self.thread.start()
        return True

    def stop(self) -> None:
        self.stopped.set()
        if self.thread.is_alive() and self.thread is not threading.current_thread():
            self.thread.join(timeout=5)

    def _run(self) -> None:
        others = [i for i in range(self.count) if i != self.index]
        seen = {i: (None, time.monotonic()) for i in others}
        beat = 0
        while not self.stopped.wait(self.interval):
            beat += 1
            try:
                self.client.key_value_set(f"mara_mjx/beat/{self.index}", str(beat), True)
                values = {i: self._beat_of(i) for i in others}
            except Exception as e:
                if self.stopped.is_set():
                    return
                self._lost(
                    f"the coordinator (process 0) does not answer ({first_line(e)}): it died, "
                    "was killed or its host is unreachable"
                )
                return
            now = time.monotonic()
            for i, value in values.items():
                if value is not None and value != seen[i][0]:
                    seen[i] = (value, now)
                elif now - seen[i][1] > self.timeout and not self.stopped.is_set():
                    self._lost(
                        f"process {i} sent no sign of life for {self.timeout:g} s "
                        "(--heartbeat_timeout): it died, was killed or hangs"
                    )
                    return

    def _beat_of(self, i: int) -> str | None:
        try:
            return self.client.key_value_try_get(f"mara_mjx/beat/{i}")
        except Exception as e:  # not posted yet: NOT_FOUND; anything else: the service
            if "NOT_FOUND" in str(e) or "not found" in str(e).lower():
                return None
            raise

    def _lost(self, why: str) -> None:
        who = f"process {self.index} of {self.count}"  # (describe() may need the backend)
        print(
            f"{self.prog[0]}: error: {who} failed: {why}; its output says why. Stopping.",
            file=sys.stderr,
            flush=True,
        )
        sys.stdout.flush()
        os._exit(1)
