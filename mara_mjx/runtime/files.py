"""Writing files safely: one atomic writer, one writability check and one folder lock for
the package.

Checkpoints, exported policies, run records (JSON, progress.csv rewrites) and the trace
cache's programs all go through `write_atomic`: the bytes go to a temporary file beside the
target, which then replaces it (`os.replace`), so a reader (or a crash, or Ctrl-C
mid-write) finds the old file or the new one, never half of one. Each call's temporary
file has a name of its own, `.<target name>.<8 hex digits>.tmp` (created with O_EXCL), so
threads and processes writing the same target never touch each other's, and it gets the
permissions of an ordinary file (0666 minus the umask). A process killed mid-write (kill
-9, a power cut) leaves its temporary file behind: `remove_temporaries` deletes such files
where no other writer can be at work (a run folder, under its lock), recognising them by
that name alone. A failed write raises `WriteError`, an OSError whose message names the
target ("[Errno 28] No space left on device: 'run/eval.json'").

    write_atomic(path, b"bytes")                       # or a str (UTF-8)
    write_atomic(path, lambda f: np.savez(f, **arrays), durable=True)   # fsync first
    check_writable(folder)                             # mkdir -p, then a test file
    lock = FolderLock(folder); lock.acquire()          # False: another process holds it
"""

from __future__ import annotations

import os
import re
import secrets
from collections.abc import Callable, Collection
from pathlib import Path
from typing import BinaryIO

_NAME_KEPT = 200  # characters of the target's name in its temporary file's name
_TEMPORARY = re.compile(r"^\.(?P<target>.+)\.[0-9a-f]{8}\.tmp$", re.DOTALL)


class WriteError(OSError):
    """A file that could not be written (a full disk, a read-only folder, ...): the
    OSError's errno and strerror, with the target as its filename."""


def temporary(path: Path) -> Path:
    """A new, empty file beside `path` that no other call uses, named as every temporary
    file of the project (`remove_temporaries` recognises one a killed process left); the
    name keeps the target's first 200 characters, so a name the file system allows still
    allows its temporary."""
    while True:
        tmp = path.with_name(f".{path.name[:_NAME_KEPT]}.{secrets.token_hex(4)}.tmp")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue


def write_atomic(
    path: str | os.PathLike, data: bytes | str | Callable[[BinaryIO], None], durable: bool = False
) -> Path:
    """Replace `path` with `data` (bytes, a str written as UTF-8, or a function that
    writes into the binary file it is given), creating its folder if needed. The target
    is replaced, not written through: a symbolic link there becomes a file. `durable`:
    the file and then its folder's entry are flushed to disk (a checkpoint survives a
    power cut). On any error or interrupt the temporary file is removed, `path` is as it
    was, and the exception propagates: the file system's as a WriteError naming `path`."""
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = temporary(path)
        with open(tmp, "wb") as f:  # by name: writers such as onnx.save read f.name
            if callable(data):
                data(f)
            else:
                f.write(data.encode() if isinstance(data, str) else data)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)
        tmp = None
        if durable:
            folder = os.open(path.parent, os.O_RDONLY)
            try:
                os.fsync(folder)
            finally:
                os.close(folder)
    except WriteError:
        raise
    except OSError as e:
        raise WriteError(e.errno, e.strerror or str(e), str(path)) from e
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
    return path


def temporary_target(name: str) -> str | None:
    """The target name (its first 200 characters) of a temporary file name that
    `write_atomic` or `check_writable` makes, else None."""
    match = _TEMPORARY.match(name)
    return match.group("target") if match else None


def remove_temporaries(
    folder: str | os.PathLike, targets: Collection[str] | None = None
) -> list[Path]:
    """Delete the temporary files that writers killed mid-write left in `folder` (not its
    subfolders): those named as `write_atomic`'s, of any target or, with `targets`, of
    those target names only. Call it only where no other process may be writing those
    targets at the same time (it would take a live writer's file away). Returns what was
    deleted."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    wanted = None if targets is None else {t[:_NAME_KEPT] for t in targets}
    removed = []
    for path in folder.iterdir():
        target = temporary_target(path.name)
        if target is None or (wanted is not None and target not in wanted):
            continue
        if path.is_file() and not path.is_symlink():
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


def check_writable(folder: str | os.PathLike) -> Path:
    """Create `folder` if needed and check a file can be written there; OSError if not.
    Safe when several threads or processes check one folder at once."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    probe = None  # named `.write-test.<hex>.tmp`: remove_temporaries knows it
    try:
        probe = temporary(folder / "write-test")
    finally:
        if probe is not None:
            probe.unlink(missing_ok=True)
    return folder


class FolderLock:
    """An exclusive lock on a folder, between processes: `fcntl.flock` on the file
    `folder/name`. The kernel drops a flock when its process ends, however it ends (kill
    -9 included), so a crashed process never leaves the folder locked; the file, which
    holds the holder's process id for messages, is removed on `release` (a crashed
    process leaves it, harmless: the next `acquire` takes it over). Without fcntl (not a
    POSIX system) `acquire` always succeeds."""

    def __init__(self, folder: str | os.PathLike, name: str = ".lock"):
        self.path = Path(folder) / name
        self._fd: int | None = None

    def acquire(self) -> bool:
        """Take the lock (creating the folder if needed); False if another process holds
        it. Calling it again while holding it returns True."""
        if self._fd is not None:
            return True
        try:
            import fcntl
        except ImportError:
            return True
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                return False
            except BaseException:
                os.close(fd)
                raise
            try:  # a holder's release may have removed the file we opened: try again
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return True

    def holder(self) -> str:
        """The process id the lock file names ('' if none can be read)."""
        try:
            return self.path.read_text().strip()
        except OSError:
            return ""

    def release(self) -> None:
        """Give the lock up and remove its file (nothing if not held)."""
        if self._fd is None:
            return
        try:
            self.path.unlink(missing_ok=True)  # before unlocking: see acquire
        finally:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> FolderLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
