"""Session fixtures: each env and its jitted reset/step are built and compiled once.

Every jitted function is wrapped in a retrace guard (`max_traces`, chex's
`assert_max_traces` counted per wrapped object: chex keys its counter on the source
code, which all env instances share): a test that makes it retrace (a weak type, a
new shape, a params sweep that should not recompile) fails instead of silently
slowing everything down.
"""

from __future__ import annotations

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# The CLIs turn JAX's persistent compilation cache on (mara_mjx.runtime.jax_cache); tests never
# read or write the user's cache folder, so a run's timing does not depend on an earlier
# one. Tests that want a cache give their subprocesses a fresh temporary folder.
os.environ["MARA_MJX_COMPILATION_CACHE"] = "0"
# The CLIs set full-precision matmuls (cli.configure_jax) unless this variable is set;
# tests call them in-process, and a config change mid-session would retrace every
# jitted function of the session (the retrace guard below would fail). Set it as they do.
os.environ["JAX_DEFAULT_MATMUL_PRECISION"] = "highest"
# Compile speed: nearly all of the suite's time is XLA compiling programs that then run a
# few steps. LLVM at O0 cuts that CPU time by about a third (a tiny training CLI run: 60 s
# -> 37 s of CPU) and changes results only in their last bits (benchmarks/NOTES.md
# section 15). The tests compare runs with each other, all compiled alike (subprocesses
# inherit XLA_FLAGS); the one bit-for-bit check against recorded values
# (test_envs.py::test_fixed_target_tasks_are_unchanged_bit_for_bit) runs in its own
# process without these flags, as users compile.
FAST_COMPILE_FLAGS = "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {FAST_COMPILE_FLAGS}".strip()

import functools  # noqa: E402
import gc  # noqa: E402

# Python's full (generation 2) garbage collections: a test worker's heap grows to millions
# of objects (traced jaxprs, compiled functions, the session's cached envs), and with the
# default threshold (a full collection after 10 of generation 1, once the long-lived
# objects grew by a quarter) a worker ran one every few seconds of tracing, each scanning
# the whole heap: 10-15% of an in-process test file's CPU time (tests/test_determinism.py:
# 6 of its 32 s). One after 1000 of generation 1 instead; the young generations, which
# free most cycles, are unchanged. Collections only free memory: no result depends on it.
gc.set_threshold(*gc.get_threshold()[:2], 1000)

import jax  # noqa: E402
import jax.monitoring  # noqa: E402
import pytest  # noqa: E402

import mara_mjx  # noqa: E402

TASK_NAMES = ("MARA", "MARAOrient", "MARACollision", "MARACollisionOrient")


def max_traces(fn, n: int = 1):
    """Wrap `fn` (before jit) so that tracing it more than `n` times raises."""
    traces = 0

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        nonlocal traces
        traces += 1
        if traces > n:
            raise AssertionError(f"{getattr(fn, '__qualname__', fn)} traced {traces} > {n} times")
        return fn(*args, **kwargs)

    return wrapped


class Jitted:
    """An env with its reset, step and vmapped step jitted under a retrace guard."""

    def __init__(self, env):
        self.env = env
        self._reset = jax.jit(max_traces(env.reset, n=1))
        self.step = jax.jit(max_traces(env.step, n=1))
        self._vstep = None

    def reset(self, key, params=None):
        """env.reset(key, params), params always passed (None: the env's defaults), so
        that `reset(key)` and `reset(key, params)` share one trace."""
        return self._reset(key, self.env.default_params if params is None else params)

    @property
    def vstep(self):
        if self._vstep is None:
            self._vstep = jax.jit(max_traces(jax.vmap(self.env.step), n=1))
        return self._vstep


_COMPILED: list[str] = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, _duration, **kw: (
        _COMPILED.append(kw.get("fun_name", ""))
        if event.endswith("backend_compile_duration")
        else None
    )
)


@pytest.fixture
def compiled() -> list[str]:
    """Names of the functions XLA compiles from now on (the list a test may clear)."""
    _COMPILED.clear()
    return _COMPILED


_CACHE: dict[tuple, Jitted] = {}


def jitted(name: str, **overrides) -> Jitted:
    """The session's one Jitted for (name, overrides)."""
    key = (name, tuple(sorted(overrides.items())))
    if key not in _CACHE:
        _CACHE[key] = Jitted(mara_mjx.make(name, **overrides))
    return _CACHE[key]


@pytest.fixture(scope="session", params=TASK_NAMES)
def task(request) -> Jitted:
    return jitted(request.param)


@pytest.fixture(scope="session")
def mara() -> Jitted:
    return jitted("MARA")


@pytest.fixture(scope="session")
def orient() -> Jitted:
    return jitted("MARACollisionOrient")


@pytest.fixture(scope="session")
def cli_env(tmp_path_factory) -> dict[str, str]:
    """The environment of the CLI subprocesses (tests/test_train_cli.py and others): the
    CPU, and a persistent compilation cache in a temporary folder shared by the session's
    subprocesses (so a resumed run or an evaluation reuses a training run's programs). Under
    xdist the folder is shared by every worker of the session (the parent of the workers'
    base folders): test files on different workers train the same tiny programs. Entries
    are written atomically (mara_mjx/runtime/jax_cache.py), so workers may share it."""
    base = tmp_path_factory.getbasetemp()
    cache = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "jax_cache_cli"
    cache.mkdir(exist_ok=True)
    return {
        **os.environ,
        "JAX_PLATFORMS": "cpu",
        "MARA_MJX_COMPILATION_CACHE": str(cache),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0",
    }
