"""mara_mjx.runtime.files: the one atomic writer (checkpoints, exports, JSON records, the trace
cache) and the writability check, under interrupts, errors and concurrent writers."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from mara_mjx.runtime import files


def _leftovers(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def test_writes_bytes_text_and_a_writer_function(tmp_path):
    target = tmp_path / "new" / "folder" / "a.bin"  # folders are created
    assert files.write_atomic(target, b"\x00\x01") == target
    assert target.read_bytes() == b"\x00\x01"
    files.write_atomic(target, "héllo\n")  # a str is UTF-8
    assert target.read_text(encoding="utf-8") == "héllo\n"
    arrays = {"x": np.arange(3)}
    files.write_atomic(target, lambda f: np.savez(f, **arrays), durable=True)
    assert np.array_equal(np.load(target)["x"], arrays["x"])
    assert _leftovers(target.parent) == []


@pytest.mark.parametrize("error", [KeyboardInterrupt, OSError])
def test_an_interrupted_write_leaves_the_old_file_and_no_temporary(tmp_path, error):
    target = tmp_path / "checkpoint.npz"
    target.write_bytes(b"old, complete")

    def half_then_stop(f):
        f.write(b"half of the new")
        raise error("stopped mid-write")

    with pytest.raises(error):
        files.write_atomic(target, half_then_stop)
    assert target.read_bytes() == b"old, complete"
    assert _leftovers(tmp_path) == []


def test_files_get_ordinary_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        path = files.write_atomic(tmp_path / "x.json", "{}")
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644


def test_concurrent_writers_of_one_file_each_finish_and_one_wins_whole(tmp_path):
    """Threads of one process (the old pid-named temporary file was shared by them: one
    thread's rename took another's file away) and the writability check beside them."""
    target = tmp_path / "record.json"
    payloads = [(f"writer {i} " * 2000).encode() for i in range(8)]
    barrier = threading.Barrier(8)

    def write(i):
        barrier.wait()
        for _ in range(30):
            files.write_atomic(target, payloads[i])
            files.check_writable(tmp_path)

    with ThreadPoolExecutor(8) as pool:
        list(pool.map(write, range(8)))  # re-raises any thread's error
    assert target.read_bytes() in payloads
    assert [p.name for p in tmp_path.iterdir()] == ["record.json"]


def test_check_writable_creates_the_folder_and_names_the_problem(tmp_path):
    assert files.check_writable(tmp_path / "a" / "b").is_dir()
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(OSError):
        files.check_writable(blocker / "sub")  # a file where a folder should be


def test_a_name_the_file_system_allows_can_be_written(tmp_path):
    """The temporary file's name keeps the target's first 200 characters, so a target
    name of 255 characters (NAME_MAX on Linux) still works."""
    target = tmp_path / ("n" * 255)
    files.write_atomic(target, b"x")
    assert target.read_bytes() == b"x" and _leftovers(tmp_path) == []


def test_a_failed_write_names_the_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    """A full disk (ENOSPC, injected: no small file system here) is a WriteError, an
    OSError whose message names the target, and the old file stays whole."""
    import errno

    target = tmp_path / "eval.json"
    target.write_text("old")

    def full(f):
        f.write(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(files.WriteError) as failed:
        files.write_atomic(target, full)
    assert failed.value.errno == errno.ENOSPC and isinstance(failed.value, OSError)
    assert str(target) in str(failed.value) and "No space left" in str(failed.value)
    assert target.read_text() == "old" and _leftovers(tmp_path) == []


def test_remove_temporaries_deletes_only_the_writers_leftovers(tmp_path):
    """What kill -9 leaves mid-write (`.<target>.<8 hex>.tmp`) goes; any other file, even
    one ending in .tmp, stays."""
    ours = [
        ".ckpt_00000002.npz.0123abcd.tmp",
        ".config.json.deadbeef.tmp",
        ".write-test.00ff00ff.tmp",
    ]
    others = [".notes.tmp", "x.tmp", ".a.b.tmp", ".ckpt.npz.0123ABCD.tmp", "ckpt_00000001.npz"]
    for name in ours + others:
        (tmp_path / name).write_text("x")
    only = files.remove_temporaries(tmp_path, ["config.json"])
    assert [p.name for p in only] == [".config.json.deadbeef.tmp"]
    removed = files.remove_temporaries(tmp_path)
    assert sorted(p.name for p in removed) == sorted(set(ours) - {".config.json.deadbeef.tmp"})
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(others)
    # the names write_atomic really makes are recognised
    target = tmp_path / "summary.json"
    assert files.temporary_target(files.temporary(target).name) == "summary.json"


HOLD = r"""
import sys, time
from mara_mjx.runtime import files
lock = files.FolderLock(sys.argv[1])
assert lock.acquire()
print("locked", flush=True)
time.sleep(600)
"""


def test_a_folder_lock_is_exclusive_and_a_killed_holder_leaves_none(tmp_path):
    import subprocess
    import sys

    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(tmp_path)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        lock = files.FolderLock(tmp_path)
        assert not lock.acquire()
        assert lock.holder() == str(holder.pid)
    finally:
        holder.kill()  # kill -9: no clean-up runs
        holder.wait()
    assert (tmp_path / ".lock").exists()  # its file stays, its lock does not
    with files.FolderLock(tmp_path) as lock:
        assert lock.acquire() and lock.acquire()  # again while holding: True
        assert not files.FolderLock(tmp_path).acquire()  # another holder: no
    assert not (tmp_path / ".lock").exists()  # released: the file is gone
    assert files.FolderLock(tmp_path).acquire()
