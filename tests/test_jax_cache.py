"""JAX's persistent compilation cache as the CLIs set it up (mara_mjx.runtime.jax_cache).

Where the folder comes from (flag, MARA_MJX_COMPILATION_CACHE, JAX_COMPILATION_CACHE_DIR,
the per-user default), and, in fresh processes that call `configure_jax` as every CLI
does: the first writes the cache, the second loads its program from it (JAX's
`cache_hits` event), the opt-out neither reads nor writes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mara_mjx.runtime import jax_cache

REPO = Path(__file__).resolve().parents[1]
VARS = (jax_cache.ENV_VAR, "JAX_COMPILATION_CACHE_DIR", "XDG_CACHE_HOME")

# What every CLI does before compiling, then one jitted program; prints JAX's cache events.
SCRIPT = """
import json, sys
import jax, jax.monitoring
events = []
jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
from mara_mjx.cli.common import configure_jax
folder = configure_jax(sys.argv[1] if len(sys.argv) > 1 else None)
import jax.numpy as jnp
y = jax.jit(lambda x: jnp.tanh(x @ x.T).sum())(jnp.ones((8, 8)))
from jax._src import lru_cache
print(json.dumps({"folder": None if folder is None else str(folder), "y": float(y),
                  "hits": events.count("/jax/compilation_cache/cache_hits"),
                  "atomic": getattr(lru_cache.LRUCache.put, "_mara_mjx_atomic", False)}))
"""


@pytest.fixture
def clean_env(monkeypatch, tmp_path):
    for name in VARS:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    return tmp_path


def test_folder_order(clean_env, monkeypatch):
    default = clean_env / "xdg" / "mara_mjx" / "jax"
    assert jax_cache.resolve() == default
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(clean_env / "jax"))
    assert jax_cache.resolve() == clean_env / "jax"  # the user's JAX setting
    monkeypatch.setenv(jax_cache.ENV_VAR, "off")
    assert jax_cache.resolve() is None
    monkeypatch.setenv(jax_cache.ENV_VAR, str(clean_env / "mine"))
    assert jax_cache.resolve() == clean_env / "mine"
    assert jax_cache.resolve("true") == default  # the flag wins
    assert jax_cache.resolve("false") is None
    assert jax_cache.resolve(str(clean_env / "flag")) == clean_env / "flag"


def test_cli_flag_reaches_the_setup():
    from mara_mjx.bench import runner
    from mara_mjx.cli import evaluate, play, train

    for parser in (train.build_parser(), evaluate.build_parser(), play.build_parser()):
        args = parser.parse_known_args(["--compilation_cache", "false", "RUN"])[0]
        assert jax_cache.resolve(args.compilation_cache) is None
    args = runner.build_parser("").parse_args(["env", "--compilation_cache", "/tmp/x"])
    assert args.compilation_cache == "/tmp/x"


def _run(env: dict[str, str], *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", SCRIPT, *args],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _result(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-3000:]
    return json.loads(out.strip().splitlines()[-1])


def test_second_process_loads_from_the_default_folder_and_opt_out_does_not(clean_env):
    env = {k: v for k, v in os.environ.items() if k not in VARS}
    env.update(
        JAX_PLATFORMS="cpu",
        XDG_CACHE_HOME=str(clean_env / "xdg"),
        PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
        # the test's program compiles in milliseconds: write it anyway
        JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
    )
    folder = clean_env / "xdg" / "mara_mjx" / "jax"
    first = _result(_run(env))
    assert first["folder"] == str(folder) and first["hits"] == 0
    assert first["atomic"]  # jax 0.10's in-place write replaced by write + rename
    entries = sorted(p.name for p in folder.iterdir())
    assert entries and not [n for n in entries if n.endswith(".tmp")], entries

    second = _run(env)  # the two start together (the flag's value: test above)
    off = _run({**env, jax_cache.ENV_VAR: "0"})
    second, off = _result(second), _result(off)
    assert second["hits"] >= 1 and second["y"] == first["y"]
    assert off["folder"] is None and off["hits"] == 0
    assert sorted(p.name for p in folder.iterdir()) == entries


# A full disk while JAX writes an entry, simulated by RLIMIT_FSIZE (writes past LIMIT
# bytes fail with EFBIG, SIGXFSZ ignored): then the same program written with room.
FULL_DISK = """
import json, os, resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
import jax, jax.numpy as jnp
from jax._src import lru_cache, path as jax_path
from mara_mjx.cli.common import configure_jax
folder = configure_jax(sys.argv[1])
limit = int(sys.argv[2])
f = lambda x: jnp.tanh(x @ x.T).sum()
x = jnp.ones((64, 64)).block_until_ready()
listing = lambda: sorted((p.name, p.stat().st_size) for p in folder.iterdir())
before = listing()  # jnp.ones' own programs
soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
y = float(jax.jit(f)(x))
full = [e for e in listing() if e not in before]
resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
jax.clear_caches()
y2 = float(jax.jit(f)(x))
room = [e for e in listing() if e not in before]
print(json.dumps({"y": y, "y2": y2, "full": full, "room": room,
                  "path_type": type(jax_path.Path(str(folder))).__module__,
                  "atomic": getattr(lru_cache.LRUCache.put, "_mara_mjx_atomic", False)}))
"""


def test_a_full_disk_leaves_no_truncated_entry(clean_env):
    """JAX's own put (write_bytes in place) leaves LIMIT bytes of the entry under its
    final name, which every later run reads, warns about and recompiles."""
    env = {k: v for k, v in os.environ.items() if k not in VARS}
    env.update(
        JAX_PLATFORMS="cpu",
        PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
        JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
        JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0",
    )
    limit = 2048
    folder = clean_env / "cache"
    proc = subprocess.run(
        [sys.executable, "-c", FULL_DISK, str(folder), str(limit)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["atomic"] and out["y"] == out["y2"]
    print(out["path_type"])  # etils.epath.* where etils is installed, else pathlib
    assert out["full"] == [], out["full"]  # no entry, no temporary file
    (entry, size), *rest = out["room"]
    assert entry.endswith("-cache") and size > limit and not rest, out["room"]
    assert "persistent compilation cache" in proc.stderr  # JAX warned of the failed write


def test_local_path_of_the_path_types_jax_uses(tmp_path):
    """jax._src.path.Path: pathlib.Path without etils, epath.Path with it (GCS too)."""
    assert jax_cache.local_path(tmp_path) == tmp_path
    assert jax_cache.local_path(None) is None
    epath = pytest.importorskip("etils.epath")
    assert jax_cache.local_path(epath.Path(str(tmp_path))) == tmp_path
    assert jax_cache.local_path(epath.Path("gs://bucket/cache")) is None
