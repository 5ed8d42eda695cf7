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


def _temporary(path: Path) -> Path:
    """A new, empty file beside `path` that no other call uses (the name's first 200
    characters, so that a name the file system allows still allows its temporary)."""
    while True:
        tmp = path.with_name(f".{path.name[:200]}.{secrets.token_hex(4)}.tmp")
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
    was, and the exception (OSError for the file system's) propagates."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = None
    try:
        tmp = _temporary(path)
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
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
    return path


def check_writable(folder: str | os.PathLike) -> Path:
    """Create `folder` if needed and check a file can be written there; OSError if not.
    Safe when several threads or processes check one folder at once."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    probe = None
    try:
        probe = _temporary(folder / "write-test")
    finally:
        if probe is not None:
            probe.unlink(missing_ok=True)
    return folder
