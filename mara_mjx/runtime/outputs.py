"""What a CLI may write where: the files of a run folder, and the guard on every output a
user names.

An output a user points somewhere (`evaluate --json`, `export OUT`, `benchmark --out`)
  is checked before anything runs (`check_output`): never a folder, a checkpoint (any
  file of a `checkpoints/` folder or a mara_mjx checkpoint anywhere) or a file of a run
  folder (config.json, progress.csv, eval.json, summary.json, seeds.json, seeds.md, tb/,
  plots/); an existing file only when it is that command's own output from an earlier
  time (a report, an exported policy), which it replaces, or with `--overwrite`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mara_mjx.ppo.checkpoint import CHECKPOINT_DIR, FORMAT
from mara_mjx.runtime import files
from mara_mjx.runtime.npzmeta import NPZ_ERRORS, read_npz_with_meta


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
"""A multi-seed run folder's own files (mara_mjx.cli.seeds)."""
LOCK = ".lock"
"""The lock file of a run folder while a process trains it (files.FolderLock)."""


def read_json(path: str | os.PathLike) -> Any:
    """The JSON value of a file, or None when it is missing or not JSON."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def written_by(record: str | os.PathLike, command: str) -> bool:
    """True if the JSON file `record` holds a "command" that starts with `command`: a
    script's own earlier output (its `ours` for check_output_folder), which it may replace."""
    data = read_json(record)
    return isinstance(data, dict) and str(data.get("command", "")).startswith(command)


def lines_written_by(record: str | os.PathLike, key: str, values: tuple[str, ...]) -> bool:
    """True if every line of `record` is a JSON object whose `key` is one of `values`: a
    script's own earlier JSON-lines output (its `ours` for check_output), which it may
    append to."""
    try:
        rows = [json.loads(line) for line in Path(record).read_text().splitlines() if line]
    except (OSError, ValueError):
        return False
    return all(isinstance(r, dict) and r.get(key) in values for r in rows)


def check_lines_output(
    path: str | os.PathLike, what: str, key: str, values: tuple[str, ...], overwrite: bool
) -> Path:
    """check_output for a script that appends JSON lines: `path` new, or its own earlier
    lines (`lines_written_by`), or any file with `overwrite`."""
    ours = lambda record: lines_written_by(record, key, values)  # noqa: E731
    return check_output(path, what, ours, overwrite)


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
    from mara_mjx.cli.common import UserError

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


def check_output_folder(
    folder: str | os.PathLike,
    names: tuple[str, ...],
    what: str,
    ours: Callable[[], bool],
    overwrite: bool = False,
) -> Path:
    """`folder` if a script may write its fixed-name outputs `names` there (a study's
    `--out FOLDER`: NAME.json, NAME.md, NAME.png); otherwise UserError. Each name is
    checked as `check_output` checks a file; `ours()` tells whether the folder's files are
    an earlier output of the same script (read off its JSON), which are replaced."""
    from mara_mjx.cli.common import UserError

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{what} {str(folder)!r} is a file; name a folder")
    mine = ours()
    for name in names:
        check_output(folder / name, what, lambda _: mine, overwrite)
    return folder
