"""Writing files safely: one atomic writer and one writability check for the package.

Checkpoints, exported policies, run records (JSON) and the trace cache's programs all go
through `write_atomic`: the bytes go to a temporary file beside the target, which then
replaces it (`os.replace`), so a reader (or a crash, or Ctrl-C mid-write) finds the old
file or the new one, never half of one. Each call's temporary file has a name of its own
(created with O_EXCL), so threads and processes writing the same target never touch each
other's, and it gets the permissions of an ordinary file (0666 minus the umask).

    write_atomic(path, b"bytes")                       # or a str (UTF-8)
    write_atomic(path, lambda f: np.savez(f, **arrays), durable=True)   # fsync first
    check_writable(folder)                             # mkdir -p, then a test file
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def _temporary(path: Path) -> tuple[int, Path]:
    """A new file beside `path` that no other call uses (its descriptor, its path)."""
    while True:
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:
            continue


def write_atomic(
    path: str | os.PathLike, data: bytes | str | Callable[[BinaryIO], None], durable: bool = False
) -> Path:
    """Replace `path` with `data` (bytes, a str written as UTF-8, or a function that
    writes into the binary file it is given), creating its folder if needed. `durable`:
    flush to disk before the rename (a checkpoint survives a power cut). On any error or
    interrupt the temporary file is removed, `path` is as it was, and the exception
    (OSError for the file system's) propagates."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _temporary(path)
    try:
        os.close(fd)
        with open(tmp, "wb") as f:  # by name: writers such as onnx.save read f.name
            if callable(data):
                data(f)
            else:
                f.write(data.encode() if isinstance(data, str) else data)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def check_writable(folder: str | os.PathLike) -> Path:
    """Create `folder` if needed and check a file can be written there; OSError if not.
    Safe when several threads or processes check one folder at once."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fd, probe = _temporary(folder / "write-test")
    os.close(fd)
    probe.unlink()
    return folder
