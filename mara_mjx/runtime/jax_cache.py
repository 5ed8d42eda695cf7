"""JAX's persistent compilation cache, on by default for the CLIs (warm starts).

XLA compiles of the env step and the PPO update take tens of seconds on a GPU and
minutes on a CPU; with the cache, a second run of the same program (same shapes, config,
flags, jax/jaxlib and device) loads the executable from disk instead of compiling it.

Where the cache lives, first match wins:

1. `--compilation_cache VALUE` (train, evaluate, play, benchmark);
2. the environment variable `MARA_MJX_COMPILATION_CACHE=VALUE`;
3. `JAX_COMPILATION_CACHE_DIR`, if the user set it (JAX's own setting, left as is);
4. `$XDG_CACHE_HOME/mara_mjx/jax`, else `~/.cache/mara_mjx/jax`.

VALUE is `true` (the default folder of 4), `false` (no persistent cache at all, also not
JAX_COMPILATION_CACHE_DIR's) or a folder. A folder that cannot be created turns the cache
off with a one-line note on stderr.

Programs that compile in at least `MIN_COMPILE_TIME_S` are written (JAX's default, 1 s,
would skip e.g. the evaluation rollout on a GPU); `JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`
overrides it. The folder is not size-limited (JAX's limit needs the `filelock` package):
delete it at any time to reclaim the space.

Several processes may share the folder. JAX reads an entry as a whole file and, if
it cannot be decompressed or loaded, warns and compiles instead. In a `jax.distributed`
run only process 0 writes (JAX's rule). JAX's unlimited cache (`jax._src.lru_cache`,
unchanged from jax 0.10.2 to jax's 0.11.1 development tree of August 2026; 0.11.2's was
not read: where its internals differ, the guard below keeps JAX's own write) writes an
entry in place (`Path.write_bytes`), so a process could read a half-written file, and a
full disk or a killed process leaves a truncated entry that warns and recompiles on
every later run; `atomic_writes` makes each
write a temporary file renamed into place (`os.replace`, atomic on POSIX file systems),
so readers see a whole entry or none, and a failed write leaves nothing (JAX then warns
once and runs the program it compiled). JAX's cache path is `jax._src.path.Path`: etils'
`epath.Path` where etils is installed (as here: flax pulls it in), else `pathlib.Path`;
both are handled, by the local file name they stand for. A remote folder (`gs://...`,
which only epath can write) keeps JAX's own write.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from mara_mjx.runtime import files

ENV_VAR = "MARA_MJX_COMPILATION_CACHE"
MIN_COMPILE_TIME_S = 0.2
_TRUE = ("true", "1", "yes", "on")
_FALSE = ("false", "0", "no", "off")


def default_dir() -> Path:
    """$XDG_CACHE_HOME/mara_mjx/jax, else ~/.cache/mara_mjx/jax."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mara_mjx" / "jax"


def resolve(value: str | bool | None = None) -> Path | None:
    """The cache folder for a `--compilation_cache` value (None: not given), or None for
    no persistent cache. See the module docstring for the order."""
    for setting in (value, os.environ.get(ENV_VAR)):
        if setting is None or setting == "":
            continue
        if isinstance(setting, bool):
            return default_dir() if setting else None
        text = setting.strip()
        if text.lower() in _TRUE:
            return default_dir()
        if text.lower() in _FALSE:
            return None
        return Path(text).expanduser()
    user_dir = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    return Path(user_dir).expanduser() if user_dir else default_dir()


def configure(value: str | bool | None = None) -> Path | None:
    """Turn JAX's persistent compilation cache on (in the folder `resolve(value)` names)
    or off, before anything is compiled. Returns the folder in use, or None."""
    import jax

    folder = resolve(value)
    if folder is not None:
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            print(f"mara_mjx: compilation cache off: cannot create {folder}: {e}", file=sys.stderr)
            folder = None
    if folder is None:
        jax.config.update("jax_enable_compilation_cache", False)
        return None
    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    atomic_writes()
    return folder


def atomic_writes() -> bool:
    """Make JAX's unlimited file cache write each entry to a temporary file renamed into
    place. A guarded patch of JAX's private `LRUCache.put`: where JAX's internals differ
    from 0.10's (or a size limit is set, under which JAX holds a file lock), JAX's own
    write runs. Returns whether the patch is in place."""
    try:
        from jax._src import lru_cache
    except ImportError:
        return False
    cls = getattr(lru_cache, "LRUCache", None)
    suffix = getattr(lru_cache, "_CACHE_SUFFIX", None)
    if cls is None or not isinstance(suffix, str):
        return False
    if getattr(cls.put, "_mara_mjx_atomic", False):
        return True
    jax_put = cls.put

    def put(self, key: str, value: bytes) -> None:
        path = local_path(getattr(self, "path", None))
        if getattr(self, "eviction_enabled", True) or path is None or not key:
            return jax_put(self, key, value)
        final = path / f"{key}{suffix}"
        if final.exists():
            return
        files.write_atomic(final, value)

    put._mara_mjx_atomic = True  # type: ignore[attr-defined]
    cls.put = put
    return True


def local_path(path: Any) -> Path | None:
    """The local folder a cache path names (a `pathlib.Path`, or an `epath.Path` of a
    local folder: os.fspath gives its file name), else None (a remote `gs://` folder,
    or no path)."""
    if isinstance(path, Path):
        return path
    try:
        text = os.fspath(path)
    except TypeError:
        return None
    if not isinstance(text, str) or "://" in text:
        return None
    return Path(text)
