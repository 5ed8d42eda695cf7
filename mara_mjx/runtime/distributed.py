"""Several processes, one training run: `python -m mara_mjx.train` on jax.distributed.

Every process runs the same command; JAX's distributed runtime joins them into one
program whose devices are every process's devices (`jax.devices()`), so the mesh of
mara_mjx.runtime.sharding spans them all and each process steps its own devices' share of the
environments. How a process joins (flags; each also read from an environment variable):

    --coordinator HOST:PORT   MARA_COORDINATOR     process 0's address (it serves there)
    --num_processes N         MARA_NUM_PROCESSES   how many processes take part
    --process_id I            MARA_PROCESS_ID      this process, 0..N-1
    --distributed MODE        MARA_DISTRIBUTED     auto (default) or off
    --heartbeat_timeout S     MARA_HEARTBEAT_TIMEOUT  a silent process counts as dead after
                                                   S seconds (default: 100)
    --join_timeout S          MARA_JOIN_TIMEOUT    wait this long for every process to join
                                                   (default: 300)

With `auto`, a process joins when any of the first three is given, or when SLURM runs it as
one of several tasks (SLURM_NTASKS > 1): then `jax.distributed.initialize()` reads the
coordinator, the process count and the process id from SLURM, as JAX does. Otherwise the
command is an ordinary single process and none of this module does anything.

What the train CLI does differently when several processes take part:

* Only process 0 writes: the run folder (config.json, progress.csv, tb/, checkpoints,
  eval.json, summary.json, plots). Checkpoints gather the sharded state to every process
  (`gather`, a collective) and process 0 saves it; the final evaluation runs on process 0.
* Before anything is compiled, every process compares a digest of each section of its
  resolved config (env, ppo, run except the output folder, eval, versions, git commit, and
  the content of the checkpoint it resumes from) with process 0's (`check_same`), and all
  stop with an error naming the sections that differ. A process that fails before this
  point (a bad flag value, a missing checkpoint) sends its error instead, so every process
  stops with it rather than waiting for the missing one. `--devices` must be 0 (all):
  fewer would leave some processes without environments.
* Resuming: every process reads the same checkpoint (the run folder must be visible to all
  of them, e.g. on a shared file system); the comparison above checks that they did.
* A process that fails after that point leaves at once (`os._exit`), without JAX's
  shutdown barrier, which would wait for the others, blocked in a collective, until its
  own timeout. The others then fail within the heartbeat timeout, or at once where the
  collective notices the closed connection (the gloo CPU collectives do).
* A missing peer ends every other process with one line on stderr and a non-zero exit
  status within a bounded time: a process that never joins, after --join_timeout ("could
  not join the run ... not all joined within S s", exit status 2); one that dies, is
  killed or hangs once joined, after --heartbeat_timeout ("process i of N failed:
  process j sent no sign of life for S s ...", exit status 1). Each process's `Watchdog`
  thread posts a beat to the coordination service's key-value store every second and
  reads the others'. JAX's own deadlines are set later (heartbeats: twice ours plus 10 s;
  joining: ours plus 60 s), because JAX ends a process whose peer is missing with a C++
  abort and stack trace ("Terminating process because the JAX distributed service
  detected fatal errors"). When process 0, which runs the coordination service, dies,
  JAX's error polling aborts the others that way at once (SIGABRT, within a second),
  before any Python code can run: the CLI's watching parent (mara_mjx/runtime/supervise.py)
  then prints the one line ("JAX ended this process (SIGABRT) because process 0 (the
  coordinator, at HOST:PORT) died ...", exit status 1).

On CPU (the test suite) the collectives between processes are gloo's
(`jax_cpu_collectives_implementation`).
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import sys
import threading
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mara_mjx.cli.common import run_cli as run_user_cli
from mara_mjx.runtime.launch import (  # noqa: F401  (re-exported: the CLI's launch flags)
    ENV_VARS,
    MODES,
    DistributedError,
    Launch,
    Watchdog,
    add_arguments,
    first_line,
    launch_from,
)

_SLOTS, _DIGEST, _MESSAGE = 16, 8, 1024  # config sections, bytes per digest, error bytes
DEFAULT_HEARTBEAT_TIMEOUT = 100  # s, JAX's default
DEFAULT_JOIN_TIMEOUT = 300  # s, JAX's default


class _State:
    active = False  # jax.distributed initialised by this module
    exchanged = False  # the processes have compared configs (or errors)
    watchdog: Watchdog | None = None


def initialize(launch: Launch | None) -> None:
    """jax.distributed.initialize as `launch` says (nothing for None); before any other
    JAX call that starts a backend."""
    if launch is None:
        return
    import jax

    try:  # CPU processes talk through gloo (the default in recent JAX; 'none' would fail)
        if jax.config.jax_cpu_collectives_implementation in (None, "none"):
            jax.config.update("jax_cpu_collectives_implementation", "gloo")
    except AttributeError:
        pass
    accepted = inspect.signature(jax.distributed.initialize).parameters
    kwargs: dict[str, Any] = {
        "coordinator_address": launch.coordinator,
        "num_processes": launch.num_processes,
        "process_id": launch.process_id,
    }
    timeout = launch.heartbeat_timeout or DEFAULT_HEARTBEAT_TIMEOUT
    join = launch.join_timeout or DEFAULT_JOIN_TIMEOUT
    for name, value in (  # JAX's timeouts: after ours, which end the process cleanly
        ("heartbeat_timeout_seconds", 2 * timeout + 10),
        ("initialization_timeout", join + 60),
    ):
        if value is not None:
            if name not in accepted:
                raise DistributedError(f"this JAX ({jax.__version__}) has no {name} option")
            kwargs[name] = value
    where = launch.coordinator or "the coordinator SLURM names"
    failed = (
        f"could not join the run at {where} as process {launch.process_id} of "
        f"{launch.num_processes}: {{}} (did every process start, with the same "
        "--coordinator and --num_processes? --join_timeout sets how long to wait)"
    )
    # JAX aborts the process (C++) when a process is missing at its deadline: ours is first
    timer = threading.Timer(join, _not_joined, (failed.format(f"not all joined within {join} s"),))
    timer.daemon = True
    timer.start()
    try:
        jax.distributed.initialize(**kwargs)
    except Exception as e:  # JAX raises ValueError, RuntimeError or XlaRuntimeError
        raise DistributedError(failed.format(first_line(e))) from e
    finally:
        timer.cancel()
    _State.active = True
    _State.exchanged = False
    watchdog = Watchdog(timeout, _PROG)
    if watchdog.start():
        _State.watchdog = watchdog


_PROG = ["mara_mjx"]  # the CLI's name in messages (run_cli sets it)


def _not_joined(message: str) -> None:
    """The join deadline passed (a timer thread): one line, exit status 2, at once."""
    print(f"{_PROG[0]}: error: {message}", file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(2)


def active() -> bool:
    """True in a process of a multi-process run joined through this module."""
    return _State.active


def process_index() -> int:
    if not _State.active:
        return 0
    import jax

    return jax.process_index()


def process_count() -> int:
    if not _State.active:
        return 1
    import jax

    return jax.process_count()


def is_main() -> bool:
    """True in the process that writes (process 0, or the only one)."""
    return process_index() == 0


def describe() -> str:
    """'process 1 of 2' (for messages)."""
    return f"process {process_index()} of {process_count()}"


# ----------------------------------------------------------------- agreement
def _digest(value: Any) -> bytes:
    text = json.dumps(value, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).digest()[:_DIGEST]


def file_digest(path: str | os.PathLike | None) -> str | None:
    """sha256 of a file's bytes (None for None)."""
    if path is None:
        return None
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _exchange(sections: dict[str, Any] | None, error: str | None) -> np.ndarray:
    """Every process's (status, section digests, error message) row: (P, L) uint8. A
    collective: every process of the run calls it exactly once."""
    from jax.experimental import multihost_utils

    row = np.zeros(1 + _SLOTS * _DIGEST + _MESSAGE, np.uint8)
    if error is not None:
        row[0] = 1
        message = error.encode()[:_MESSAGE]
        row[1 + _SLOTS * _DIGEST : 1 + _SLOTS * _DIGEST + len(message)] = np.frombuffer(
            message, np.uint8
        )
    else:
        assert sections is not None and len(sections) <= _SLOTS, "too many config sections"
        for i, name in enumerate(sorted(sections)):
            digest = np.frombuffer(_digest(sections[name]), np.uint8)
            row[1 + i * _DIGEST : 1 + (i + 1) * _DIGEST] = digest
    _State.exchanged = True
    return np.asarray(multihost_utils.process_allgather(row))


def check_same(sections: dict[str, Any]) -> None:
    """Stop every process, with a DistributedError, if any process's `sections` (JSON-able
    values) differ from process 0's, or if a process reported an error before this point.
    A collective: the first one of the run (nothing happens with one process)."""
    if not _State.active or _State.exchanged:
        return
    rows = _exchange(sections, None)
    n = len(rows)
    for i in range(n):
        if rows[i, 0]:
            message = bytes(rows[i, 1 + _SLOTS * _DIGEST :]).rstrip(b"\0").decode(errors="replace")
            raise DistributedError(f"process {i} of {n} failed before training: {message}")
    names = sorted(sections)
    differ = {}
    for i in range(1, n):
        for k, name in enumerate(names):
            a = rows[0, 1 + k * _DIGEST : 1 + (k + 1) * _DIGEST]
            b = rows[i, 1 + k * _DIGEST : 1 + (k + 1) * _DIGEST]
            if not np.array_equal(a, b):
                differ.setdefault(name, []).append(i)
    if differ:
        which = "; ".join(
            f"{name} (process {', '.join(map(str, p))})" for name, p in differ.items()
        )
        raise DistributedError(
            f"the processes disagree with process 0 on {which}: start every process with the "
            "same flags, the same code and versions, and the same checkpoint"
        )


def check_same_config(resolved: dict[str, Any], checkpoint: Path | None) -> None:
    """check_same on the train CLI's resolved config: every top-level section, the run
    section without its output folder (only process 0 writes one; a default name holds a
    time stamp), and the resumed checkpoint's content instead of its path. Then a
    DistributedError if run.devices leaves out any process's devices."""
    if not _State.active:
        return
    sections = dict(resolved)
    sections["run"] = {k: v for k, v in resolved["run"].items() if k != "out"}
    sections["resume_from"] = file_digest(checkpoint)
    check_same(sections)
    import jax

    devices = resolved["run"].get("devices", 0)
    if devices not in (0, jax.device_count()):
        raise DistributedError(
            f"devices={devices} would leave out the devices of some of the "
            f"{jax.process_count()} processes; with several processes use them all "
            f"(devices=0, i.e. {jax.device_count()})"
        )


# ------------------------------------------------------------ data movement
def gather(tree: Any) -> Any:
    """`tree` with every array that spans several processes replaced by its whole value,
    as a local array; a collective that every process calls. Without several processes,
    `tree` itself."""
    if not _State.active:
        return tree
    import jax
    import jax.numpy as jnp
    from jax.experimental import multihost_utils

    def one(x: Any) -> Any:
        if not isinstance(x, jax.Array) or x.is_fully_addressable:
            return x
        if jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
            data = one(jax.random.key_data(x))
            return jax.random.wrap_key_data(data, impl=jax.random.key_impl(x))
        if x.is_fully_replicated:
            return jnp.asarray(np.asarray(x.addressable_data(0)))
        return jnp.asarray(multihost_utils.process_allgather(x, tiled=True))

    return jax.tree.map(one, tree)


def barrier(name: str, last: bool = False) -> None:
    """Wait until every process gets here (a collective; nothing with one process).
    `last`: the run's last one, after which the processes may end at different times
    (the watchdog stops)."""
    if _State.active:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)
        if last and _State.watchdog is not None:
            _State.watchdog.stop()


class NoLog:
    """What the processes other than 0 log to: nothing (RunLogger's interface)."""

    def __init__(self, columns: tuple[str, ...]):
        self.columns = columns

    def log(self, rows: list[dict[str, float]]) -> None:
        pass

    def close(self) -> None:
        pass


# ------------------------------------------------------------------- the CLI
def run_cli(
    main: Callable[[list[str] | None], int], prog: str, argv: list[str] | None = None
) -> int:
    """flags.run_cli(main, prog, argv) (user errors as one line, exit status 2), so
    that in a multi-process run every process stops when one fails:

    * before the config comparison, the failing process sends its error through it, so
      the others stop with "process i of N failed before training: ...";
    * after it, the failing process leaves at once (os._exit, module docstring) and the
      others fail in their next collective or when its heartbeats stop.
    """

    _PROG[0] = prog

    def guarded(argv: list[str] | None) -> int:
        try:
            return main(argv)
        except BaseException as e:
            if _State.active and not _State.exchanged and not isinstance(e, SystemExit):
                try:
                    _exchange(None, f"{type(e).__name__}: {first_line(e)}")
                except Exception:
                    pass  # the others are gone too
            raise

    try:
        code = run_user_cli(guarded, prog, argv)
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
        if not _State.active:
            raise
    except BaseException as e:
        if not _State.active:
            raise
        traceback.print_exc()
        print(
            f"{prog}: error: {describe()} failed: {first_line(e)}; if another process "
            "died or was killed, its output says why",
            file=sys.stderr,
        )
        code = 1
    if _State.active and code != 0:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code
