"""Run folders: where a run's files live, what wrote them, and the env a run trained on.

A run folder (`python -m mara_mjx.train --out`, default runs/<env>-<timestamp>) holds
config.json, progress.csv, tb/, checkpoints/ckpt_<update>.npz (`mara_mjx.ppo.checkpoint`
reads and writes those), and at the end eval.json, summary.json and plots/. This module
has the folder-level pieces the CLIs share: preparing a training run's folder (never
mixing a new run into an old one), pruning old checkpoints, JSON written
atomically, a writability probe, the provenance (versions, git commit) stored with every
checkpoint and report, the guard that keeps other files out of `checkpoints/`, and
rebuilding a run's env from its saved config.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import signal
import subprocess
import sys
import threading
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


class Interrupted(KeyboardInterrupt):
    """A run stopped on Ctrl-C after writing a checkpoint of its last completed update."""


class StopRequest:
    """While active (a context manager), the first SIGINT (Ctrl-C) only sets `requested`,
    so the host loop can finish the jitted call in flight and write a checkpoint; a second
    one raises KeyboardInterrupt at once. Outside the main thread it does nothing (only
    the main thread may install signal handlers) and Ctrl-C behaves as usual."""

    def __init__(self, message: str):
        self.message = message
        self.requested = False
        self._previous = None

    def _handle(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        print(f"\n{self.message}", file=sys.stderr, flush=True)

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None


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
    """Write `data` as indented JSON, atomically (mara_mjx.files)."""
    return files.write_atomic(path, json.dumps(data, indent=2) + "\n")


def prepare_run_folder(out: Path, checkpoint: Path | None, source_run: Path | None) -> None:
    """Create a training run's folder `out` (resuming `checkpoint` of the run folder
    `source_run`, or a new run when None); UserError when it cannot be written or would
    mix a new run into an existing one."""
    from mara_mjx.cli import UserError

    try:
        files.check_writable(out)
        files.check_writable(out / CHECKPOINT_DIR)
    except OSError as e:
        raise UserError(f"cannot write to the output folder {str(out)!r}: {e}") from e
    existing = list_checkpoints(out)
    if checkpoint is None and existing:
        raise UserError(
            f"output folder {str(out)!r} already holds a run; continue it with "
            f"--resume {out} or choose another --out"
        )
    if checkpoint is None and (out / "progress.csv").exists():
        # a run stopped before its first checkpoint: nothing to resume, so start it over
        print(f"{out} holds a run stopped before its first checkpoint; starting over")
        shutil.rmtree(out / "tb", ignore_errors=True)
    if checkpoint is not None and source_run != out.resolve():
        newer = [p for p in existing if p.name > checkpoint.name]
        if newer:
            raise UserError(f"output folder {str(out)!r} holds newer checkpoints {newer}")
        source_csv = source_run / "progress.csv"
        if source_csv.exists() and not (out / "progress.csv").exists():
            (out / "progress.csv").write_bytes(source_csv.read_bytes())


def interrupted_message(out: Path) -> str:
    """What a training run stopped by Ctrl-C says about resuming it."""
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
