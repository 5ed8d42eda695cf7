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
* An output a user points somewhere (`evaluate --json`, `export OUT`, `benchmark --out`)
  is checked before anything runs (`check_output`): never a folder, a checkpoint (any
  file of a `checkpoints/` folder or a mara_mjx checkpoint anywhere) or a file of a run
  folder (config.json, progress.csv, eval.json, summary.json, seeds.json, seeds.md, tb/,
  plots/); an existing file only when it is that command's own output from an earlier
  time (a report, an exported policy), which it replaces, or with `--overwrite`.
* Every rewrite is atomic (`mara_mjx.files`): a reader, a crash or Ctrl-C finds the old
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

from mara_mjx import files
from mara_mjx.npzmeta import NPZ_ERRORS, read_npz_with_meta
from mara_mjx.ppo.checkpoint import (
    CHECKPOINT_DIR,
    FORMAT,
    CheckpointError,
    list_checkpoints,
    load_checkpoint,
)


def run_dir_of(checkpoint: Path) -> Path:
    """The run folder a checkpoint belongs to."""
    parent = checkpoint.resolve().parent
    return parent.parent if parent.name == CHECKPOINT_DIR else parent


def prune_checkpoints(run_dir: str | os.PathLike, keep: int) -> None:
    """Delete all but the newest `keep` checkpoints of a run folder."""
    for old in list_checkpoints(run_dir)[:-keep]:
        old.unlink(missing_ok=True)


def check_not_checkpoint(path: str | os.PathLike, what: str) -> None:
    """ValueError if writing `path` would replace a training checkpoint or put a file among
    a run's checkpoints: anything inside a `checkpoints/` folder, or an existing file that
    is a mara_mjx checkpoint. `what` names the file in the message ("export output")."""
    path = Path(path)
    if path.resolve().parent.name == CHECKPOINT_DIR:
        raise ValueError(
            f"{what} {str(path)!r} is inside a run's {CHECKPOINT_DIR}/ folder, which holds "
            "training checkpoints only; write it elsewhere (e.g. next to the run folder)"
        )
    if path.is_file():
        try:
            _, meta = read_npz_with_meta(path)
        except NPZ_ERRORS:
            return
        if isinstance(meta, dict) and meta.get("format") == FORMAT:
            raise ValueError(
                f"{what} {str(path)!r} is a training checkpoint; writing there would destroy "
                "it. Choose another file name"
            )


RUN_FILES = ("config.json", "progress.csv", "eval.json", "summary.json")
"""A run folder's own files (besides checkpoints/, tb/ and plots/)."""
GROUP_FILES = ("seeds.json", "seeds.md")
"""A multi-seed run folder's own files (mara_mjx.seeds)."""
LOCK = ".lock"
"""The lock file of a run folder while a process trains it (files.FolderLock)."""


def read_json(path: str | os.PathLike) -> Any:
    """The JSON value of a file, or None when it is missing or not JSON."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def is_run_folder(folder: str | os.PathLike) -> bool:
    """True if `folder` holds the config.json of a mara_mjx training run."""
    config = read_json(Path(folder) / "config.json")
    return isinstance(config, dict) and {"env_name", "ppo", "run"} <= config.keys()


def is_group_folder(folder: str | os.PathLike) -> bool:
    """True if `folder` holds the seeds.json of a mara_mjx multi-seed run."""
    group = read_json(Path(folder) / GROUP_FILES[0])
    return isinstance(group, dict) and isinstance(group.get("seeds"), list)


def _leftover(path: Path) -> bool:
    """A file or folder a killed run may leave in a folder that holds nothing else: the
    lock, a temporary file of files.write_atomic, an empty checkpoints/ folder."""
    if path.name == LOCK or files.temporary_target(path.name) is not None:
        return path.is_file()
    if path.name == CHECKPOINT_DIR and path.is_dir():
        return all(_leftover(p) for p in path.iterdir())
    return False


def is_empty(folder: str | os.PathLike) -> bool:
    """True if `folder` is missing or holds nothing but what a killed run leaves."""
    folder = Path(folder)
    return not folder.is_dir() or all(_leftover(p) for p in folder.iterdir())


def _run_file(path: Path) -> str | None:
    """What `path` is if it is a file of a run folder (for messages), else None."""
    parent = path.parent
    if path.name == LOCK:
        return "a run folder's lock file"
    if path.name in RUN_FILES and is_run_folder(parent):
        return f"the {path.name} of the run folder {str(parent)!r}"
    if path.name in GROUP_FILES and is_group_folder(parent):
        return f"the {path.name} of the multi-seed run folder {str(parent)!r}"
    if parent.name in ("tb", "plots") and is_run_folder(parent.parent):
        return f"a file of the {parent.name}/ folder of the run {str(parent.parent)!r}"
    return None


def check_output(
    path: str | os.PathLike,
    what: str,
    ours: Callable[[Path], bool] | None = None,
    overwrite: bool = False,
) -> Path:
    """`path` if a CLI may write its output there; otherwise UserError naming the problem
    and the way out. `what` names the output in messages ("--json report"); `ours(path)`
    recognises an earlier output of the same command, which is replaced; `overwrite`
    (the CLI's --overwrite) allows replacing any other existing file. Never allowed: a
    folder, a checkpoint, a file of a run folder (module docstring). The folder must be
    writable (it is created if missing)."""
    from mara_mjx.cli import UserError

    path = Path(path)
    if path.is_dir():
        raise UserError(
            f"{what} {str(path)!r} is a folder; name a file (e.g. {str(path / 'report.json')!r})"
        )
    try:
        check_not_checkpoint(path, what)
    except ValueError as e:
        raise UserError(str(e)) from e
    own = _run_file(path)
    if own is not None:
        raise UserError(
            f"{what} {str(path)!r} is {own}; writing there would replace it. Choose "
            "another file name"
        )
    if (path.exists() or path.is_symlink()) and not overwrite and not (ours and ours(path)):
        raise UserError(
            f"{what} {str(path)!r} exists and was not written by this command; choose "
            "another file name, or pass --overwrite to replace it"
        )
    try:
        files.check_writable(path.parent)
    except OSError as e:
        raise UserError(f"cannot write the {what} to {str(path)!r}: {e}") from e
    return path


def is_report(path: Path) -> bool:
    """True for a JSON report of `python -m mara_mjx.evaluate` (any kind: the paper's
    table, several seeds, held-out targets), which a later evaluation may replace."""
    report = read_json(path)
    return (
        isinstance(report, dict)
        and "env_name" in report
        and "versions" in report
        and ("episodes" in report or "per_seed" in report)
    )


def companion_of(report: Path) -> Callable[[Path], bool]:
    """`ours` for a file written beside the JSON `report` (its .md, .png): an earlier
    evaluation's if that report is one."""
    return lambda path: is_report(report)


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
    """Write `data` as indented JSON, atomically (mara_mjx.files; files.WriteError if it
    cannot)."""
    return files.write_atomic(path, json.dumps(data, indent=2) + "\n")


IDENTITY = ("env_name", "env_config", "ppo")
"""What makes two checkpoints the same run's (the run section may change on resume)."""


def differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """The IDENTITY sections in which two configs (config.json, a checkpoint's meta)
    differ; of the dicts, only the fields both have count (a newer version may add
    fields)."""
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
    """Lock `out` for this process (creating it); UserError if another process holds it.
    The caller keeps the returned lock for as long as it writes there (it is dropped when
    the process ends, whatever the cause)."""
    from mara_mjx.cli import UserError

    lock = files.FolderLock(out, LOCK)
    try:
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
    from mara_mjx.cli import UserError
    from mara_mjx.ppo import logger

    out = Path(out)
    if out.is_dir() and not is_empty(out) and not is_run_folder(out):
        group = " (the folder of a multi-seed run: --resume it)" if is_group_folder(out) else ""
        raise UserError(
            f"output folder {str(out)!r} exists and is not a mara_mjx run folder{group}; "
            "nothing was changed there. Choose a new or empty folder for --out"
        )
    try:
        files.check_writable(out)
    except OSError as e:
        raise UserError(f"cannot write to the output folder {str(out)!r}: {e}") from e
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
    out["jax_backend"] = jax.default_backend()
    out["devices"] = [str(d.device_kind) for d in jax.devices()]
    return out


def git_commit() -> str | None:
    """HEAD of the source checkout this package runs from ('+dirty' if modified), or None
    (an installed package: its folder is no checkout of mara_mjx)."""
    root = Path(__file__).resolve().parents[1]
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
