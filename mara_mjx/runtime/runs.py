"""Run folders: where a run's files live, what wrote them, and the env a run trained on.

A run folder (`python -m mara_mjx.train --out`, default runs/<env>-<timestamp>) holds
config.json, progress.csv, tb/, checkpoints/ckpt_<update>.npz (`mara_mjx.ppo.checkpoint`
reads and writes those), and at the end eval.json, summary.json and plots/. This module
has the folder-level pieces the CLIs share: preparing a training run's folder, pruning old
checkpoints, JSON written atomically, the provenance (versions, git commit) stored with
every checkpoint and report, the guard on every output a user names, stopping on
Ctrl-C or SIGTERM, and rebuilding a run's env from its saved config.

What the CLIs write, and what they never replace:

* A run folder is one run's, written by one process at a time: training takes a lock on
  it (`files.FolderLock`, the file `.lock` while it runs; a crashed process leaves no
  stale lock), and a second command on the same folder stops with an error naming the
  process that holds it. `--out` must be a new or empty folder, or a mara_mjx run folder
  (its config.json): an existing folder of anything else is refused, never cleaned. A
  run folder that holds checkpoints is only continued by `--resume`, and only with a
  checkpoint of the same run (env, env config and PPO config as its config.json):
  another run's or another task's checkpoint is refused. On taking the lock, training
  deletes the temporary files a killed writer left in the folder (`.<name>.<hex>.tmp`).
* An output a user points somewhere: `mara_mjx.runtime.outputs`.
* Every rewrite is atomic (`mara_mjx.runtime.files`): a reader, a crash or Ctrl-C finds the old
  file or the new one. A write that fails (a full disk) is one line naming the file.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

from mara_mjx.ppo.checkpoint import (
    CHECKPOINT_DIR,
    CheckpointError,
    list_checkpoints,
    load_checkpoint,
)
from mara_mjx.runtime import files
from mara_mjx.runtime.outputs import (
    LOCK,
    RUN_FILES,
    is_empty,
    is_group_folder,
    is_run_folder,
    read_json,
)


def run_dir_of(checkpoint: Path) -> Path:
    """The run folder a checkpoint belongs to."""
    parent = checkpoint.resolve().parent
    return parent.parent if parent.name == CHECKPOINT_DIR else parent


def prune_checkpoints(run_dir: str | os.PathLike, keep: int) -> None:
    """Delete all but the newest `keep` checkpoints of a run folder."""
    for old in list_checkpoints(run_dir)[:-keep]:
        old.unlink(missing_ok=True)


_STOP_SIGNAL: list[int] = []  # the stop signals received by this process, in order


def exit_status(default: int = 130) -> int:
    """128 + the first stop signal received (130 for SIGINT, 143 for SIGTERM), as a shell
    reports a process killed by it; `default` when none was received."""
    return 128 + _STOP_SIGNAL[0] if _STOP_SIGNAL else default


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While active (a CLI's command), SIGTERM (what a cluster scheduler sends) raises
    KeyboardInterrupt in the main thread, as Ctrl-C does (outside `StopRequest`); the
    signals received count for `exit_status` from its start. Nothing outside the main
    thread."""
    _STOP_SIGNAL.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_reporting(command: Callable[[], int], prog: str, what: str) -> int:
    """`command()` of a CLI that writes one report at its end (evaluate's, pick's): SIGTERM
    handled as Ctrl-C (`sigterm_as_interrupt`), either ending it with one line
    ("interrupted; no {what} was written") and the signal's exit status; a failed write
    (a full disk) a UserError naming the file."""
    from mara_mjx.cli.common import UserError

    try:
        with sigterm_as_interrupt():
            return command()
    except files.WriteError as e:
        raise UserError(f"cannot write {e.filename!r}: {e.strerror}") from e
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: nothing was written
        print(f"\n{prog}: interrupted; no {what} was written", file=sys.stderr)
        return exit_status()


def _raise_interrupt(signum, frame) -> None:
    _STOP_SIGNAL.append(signum)
    raise KeyboardInterrupt


class Interrupted(KeyboardInterrupt):
    """A run stopped on Ctrl-C or SIGTERM after writing a checkpoint of its last completed
    update."""


SIGNAL_NAMES = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}


class StopRequest:
    """While active (a context manager), the first SIGINT (Ctrl-C) or SIGTERM (a
    scheduler's stop) only sets `requested`, so the host loop can finish the jitted call
    in flight and write a checkpoint; a second one raises KeyboardInterrupt at once. The
    message printed is `message` after the signal's name. Outside the main thread it
    does nothing (only the main thread may install signal handlers) and the signals
    behave as before."""

    def __init__(self, message: str):
        self.message = message
        self.requested = False
        self._previous: dict[int, Any] = {}

    def _handle(self, signum, frame) -> None:
        _STOP_SIGNAL.append(signum)
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        name = SIGNAL_NAMES.get(signum, f"signal {signum}")
        print(f"\n{name}: {self.message}", file=sys.stderr, flush=True)

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            for signum in SIGNAL_NAMES:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)
        self._previous = {}


def env_overrides(env_config: dict[str, Any]) -> dict[str, Any]:
    """`make(name, **env_overrides(cfg))` rebuilds an env from `EnvConfig.to_dict()`."""
    flat = {k: v for k, v in env_config.items() if k != "reward"}
    flat.update(env_config.get("reward", {}))
    return flat


def make_env(meta: dict[str, Any], **overrides: Any):
    """The env a checkpoint was trained on (its saved name and config), with `overrides`
    (EnvConfig fields) on top; CheckpointError if the env is not registered, the options
    are invalid, or its observation size is not the policy's."""
    from mara_mjx.envs import make, registered

    name = meta["env_name"]
    if name not in registered():
        raise CheckpointError(
            f"checkpoint env {name!r} is not registered; registered: {registered()}"
        )
    saved = env_overrides(meta["env_config"])
    if isinstance(overrides.get("randomization"), dict):  # some fields: on top of the saved
        overrides = {**overrides, "randomization": {
            **saved.get("randomization", {}), **overrides["randomization"]}}  # fmt: skip
    try:
        env = make(name, **{**saved, **overrides})
    except ValueError as e:
        raise CheckpointError(f"cannot build env {name}: {e}") from e
    if env.observation_size != meta["observation_size"]:
        raise CheckpointError(
            f"env {name} observes {env.observation_size} values, the policy expects "
            f"{meta['observation_size']}"
        )
    return env


def write_json(path: str | os.PathLike, data: Any) -> Path:
    """Write `data` as indented JSON, atomically (mara_mjx.runtime.files; files.WriteError if it
    cannot)."""
    return files.write_atomic(path, json.dumps(data, indent=2) + "\n")


IDENTITY = ("env_name", "env_config", "ppo", "policy", "curriculum")
"""What makes two checkpoints the same run's (the run section may change on resume)."""


def differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """The IDENTITY sections in which two configs (config.json, a checkpoint's meta)
    differ; of the dicts, only the fields both have count (a newer version may add
    fields; a pre-split config.json is compared in the present layout)."""
    from mara_mjx.ppo.config import upgrade_meta

    a, b = upgrade_meta(a), upgrade_meta(b)
    differ = []
    for key in IDENTITY:
        x, y = a.get(key), b.get(key)
        if isinstance(x, dict) and isinstance(y, dict):
            x, y = ({k: d[k] for k in x.keys() & y.keys()} for d in (x, y))
        if x != y:
            differ.append(key)
    return differ


def describe_run(meta: dict[str, Any]) -> str:
    """'MARA, seed 0' (for messages)."""
    seed = meta.get("ppo", {}).get("seed") if isinstance(meta.get("ppo"), dict) else None
    return f"{meta.get('env_name')}" + ("" if seed is None else f", seed {seed}")


def claim_folder(out: Path, what: str = "run folder") -> files.FolderLock:
    """Lock `out` for this process (creating it); UserError if it cannot be written or
    another process holds it. The caller keeps the returned lock for as long as it writes
    there (it is dropped when the process ends, whatever the cause)."""
    from mara_mjx.cli.common import UserError

    lock = files.FolderLock(out, LOCK)
    try:
        files.check_writable(out)
        taken = lock.acquire()
    except OSError as e:
        raise UserError(f"cannot write to the output folder {str(out)!r}: {e}") from e
    if not taken:
        holder = lock.holder()
        raise UserError(
            f"{what} {str(out)!r} is in use by another mara_mjx process"
            + (f" (pid {holder})" if holder else "")
            + "; wait for it to end (or stop it), or choose another --out"
        )
    return lock


def prepare_run_folder(
    out: Path,
    checkpoint: Path | None,
    source_run: Path | None,
    meta: dict[str, Any] | None = None,
) -> files.FolderLock:
    """Create and lock a training run's folder `out` (resuming `checkpoint`, whose meta
    is `meta` (read if None), of the run folder `source_run`, or a new run when None);
    UserError when it is not writable, is in use, is not a mara_mjx run folder, or would
    mix a new run or another run's checkpoint into an existing one. Returns the lock,
    which the caller holds while it trains."""
    from mara_mjx.cli.common import UserError
    from mara_mjx.ppo import logger

    out = Path(out)
    if out.is_dir() and not is_empty(out) and not is_run_folder(out):
        group = " (the folder of a multi-seed run: --resume it)" if is_group_folder(out) else ""
        raise UserError(
            f"output folder {str(out)!r} exists and is not a mara_mjx run folder{group}; "
            "nothing was changed there. Choose a new or empty folder for --out"
        )
    lock = claim_folder(out)
    try:
        files.remove_temporaries(out, (*RUN_FILES, "write-test"))
        files.remove_temporaries(out / CHECKPOINT_DIR)  # only the lock holder writes there
        files.check_writable(out / CHECKPOINT_DIR)
        existing = list_checkpoints(out)
        if checkpoint is None and existing:
            raise UserError(
                f"output folder {str(out)!r} already holds a run; continue it with "
                f"--resume {out} or choose another --out"
            )
        if checkpoint is None and (out / "progress.csv").exists():
            # a run of ours stopped before its first checkpoint: nothing to resume, so
            # start it over (its TensorBoard events go, the rest is rewritten)
            print(f"{out} holds a run stopped before its first checkpoint; starting over")
            for events in (out / "tb").glob("events.out.tfevents.*"):
                events.unlink(missing_ok=True)
        if checkpoint is not None:
            if meta is None:
                meta = load_checkpoint(checkpoint)[1]
            config = read_json(out / "config.json") if is_run_folder(out) else None
            differ = differences(config, meta) if config is not None else []
            if differ:
                raise UserError(
                    f"checkpoint {str(checkpoint)!r} is not of the run in {str(out)!r}: "
                    f"it is {describe_run(meta)}, the folder's config.json is "
                    f"{describe_run(config)} (they differ in {', '.join(differ)}); resume "
                    "a run from its own checkpoints, or give --out a new folder"
                )
        if checkpoint is not None and source_run != out.resolve():
            newer = [p for p in existing if p.name > checkpoint.name]
            if newer:
                raise UserError(f"output folder {str(out)!r} holds newer checkpoints {newer}")
            source_csv = source_run / "progress.csv"
            if source_csv.exists() and not (out / "progress.csv").exists():
                files.write_atomic(out / "progress.csv", source_csv.read_bytes())
        if checkpoint is not None and (out / "progress.csv").exists():
            try:
                logger.check_progress(out / "progress.csv")
            except ValueError as e:
                raise UserError(
                    f"{e}; it cannot be continued: move it away to resume with a new "
                    "progress.csv (the earlier rows stay in the moved file)"
                ) from e
    except BaseException:
        lock.release()
        raise
    return lock


def interrupted_message(out: Path) -> str:
    """What a training run stopped by Ctrl-C or SIGTERM says about resuming it."""
    found = list_checkpoints(out)
    if found:
        return f"interrupted; {found[-1].name} is the newest checkpoint: --resume {out}"
    return (
        f"interrupted before the first checkpoint; {out} holds none, so the same command "
        "(same --out) starts the run over"
    )


def provenance() -> dict[str, Any]:
    """Versions of the software that matters for reproducing a run, and the git commit."""
    return {"versions": versions(), "git_commit": git_commit()}


def versions() -> dict[str, Any]:
    """Python's and the packages' versions, JAX's backend and the devices' kinds."""
    import jax

    out: dict[str, Any] = {"python": platform.python_version()}
    for package in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax", "numpy", "mara_mjx"):
        try:
            out[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            out[package] = None
    if out["mara_mjx"] is None:  # run from a source tree on PYTHONPATH, not installed
        from mara_mjx import __version__

        out["mara_mjx"] = __version__
    out["jax_backend"] = jax.default_backend()
    out["devices"] = [str(d.device_kind) for d in jax.devices()]
    return out


GIT_COMMIT_ENV = "MARA_MJX_GIT_COMMIT"
"""Names the commit of a copy of the source tree (e.g. the one a GPU machine runs:
benchmarks/gpu/lib.sh reads it from the tree's SOURCE_COMMIT file). It wins over the
copy's own .git, which may be older than the tree sent with it (measured: a device copy
carried the session's first HEAD, so every run there read as that commit, +dirty)."""


def git_commit() -> str | None:
    """$MARA_MJX_GIT_COMMIT if set (a copy of the tree, e.g. a GPU machine's); else HEAD
    of the source checkout this package runs from ('+dirty' if modified); else None (an
    installed package: its folder is no checkout of mara_mjx)."""
    if os.environ.get(GIT_COMMIT_ENV):
        return os.environ[GIT_COMMIT_ENV]
    root = Path(__file__).resolve().parents[2]  # mara_mjx/runtime/runs.py -> the tree
    if not (root / "pyproject.toml").is_file() or not (root / ".git").exists():
        return None
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5
        )
        if commit.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=5,
        )
        return commit.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None
