"""Phase timer for `python -m mara_mjx.train` (issue 35, the warm start; benchmarks/NOTES.md
section 61): imports, env build, the trace cache, each program's compile or cache load
(JAX's compilation-cache internals patched), the first calls and the outputs, as seconds
from this process's start, into OUT.json (and OUT.json.exit: the time at exit).

    python benchmarks/warm_start_profile.py OUT.json [--bg] -- TRAIN ARGS...  # OUT.json: new
    python benchmarks/warm_start_table.py OUT1.json OUT2.json ...   # the phase table

--bg forces ppo.warmup's background compile (a GPU host's path; off on fewer than 4
cores). Monkeypatches only: the package is not changed. Written by a helper at 3e8de8e
against jax 0.10.2's internals (jax._src.compiler, compilation_cache); another jax may
need it adapted."""

import os
import sys
import time


def _proc_start():
    with open("/proc/self/stat") as f:
        ticks = int(f.read().rsplit(")", 1)[1].split()[19])
    with open("/proc/uptime") as f:
        up = float(f.read().split()[0])
    return time.monotonic() - max(0.0, up - ticks / os.sysconf("SC_CLK_TCK"))


T0 = _proc_start()
_OUT0 = sys.argv[1]
_taken = [p for p in (_OUT0, _OUT0 + ".exit", _OUT0 + ".exit0") if os.path.exists(p)]
if _taken:  # never replaces a file (a user's, or an earlier run's timings)
    sys.exit(f"error: {_taken[0]} exists; name a new OUT.json")
import atexit as _atexit  # noqa: E402  (after the start time: it is what is timed)


def _last():
    with open(_OUT0 + ".exit", "w") as f:
        f.write(str(time.monotonic() - T0))


_atexit.register(_last)  # registered first: runs last among atexit handlers
W0 = time.monotonic() - T0  # wrapper's first line (interpreter start-up before it)
import json  # noqa: E402
import threading  # noqa: E402

OUT = sys.argv[1]
rest = sys.argv[2:]
BG = False
if rest and rest[0] == "--bg":  # force ppo.warmup's background compile (a GPU host's path)
    BG = True
    rest = rest[1:]
assert rest[0] == "--"
ARGV = rest[1:]

EVENTS = []  # (name, start, end, thread, extra)
MARKS = [("wrapper_first_line", W0)]


def now():
    return time.monotonic() - T0


def mark(name):
    MARKS.append((name, now()))


def timed(name, fn, block=False):
    def wrapper(*a, **k):
        s = now()
        try:
            out = fn(*a, **k)
            if block:
                import jax

                jax.block_until_ready(out)
            return out
        finally:
            EVENTS.append((name, s, now(), threading.current_thread().name, None))

    wrapper.__wrapped__ = fn
    if hasattr(fn, "lower"):
        wrapper.lower = fn.lower
    return wrapper


def patch(obj, attr, name=None, block=False):
    setattr(obj, attr, timed(name or attr, getattr(obj, attr), block))


# ---------------------------------------------------------------- imports
s = now()
import jax  # noqa: E402

EVENTS.append(("import jax", s, now(), "MainThread", None))
s = now()
import mujoco  # noqa: E402,F401

EVENTS.append(("import mujoco", s, now(), "MainThread", None))
s = now()
import mara_mjx.cli.train as cli  # noqa: E402

EVENTS.append(("import mara_mjx.cli.train (rest)", s, now(), "MainThread", None))
mark("imports_done")
MODS_AFTER_IMPORT = set(sys.modules)

# ---------------------------------------------------------------- jax monitoring
from jax import monitoring  # noqa: E402

DUR = []


def _dur(event, secs, **kw):
    DUR.append((event, secs, now(), threading.current_thread().name, kw.get("fun_name")))


monitoring.register_event_duration_secs_listener(_dur)

# persistent-cache internals: key, file read, decompress, deserialize per module
from jax._src import compilation_cache as cc  # noqa: E402
from jax._src import compiler  # noqa: E402

PROGRAMS = []  # one per compile_or_get_cached call
_tls = threading.local()
_orig_cogc = compiler.compile_or_get_cached


def cogc(backend, computation, *a, **k):
    from jax._src.lib.mlir import ir

    name = ir.StringAttr(computation.operation.attributes["sym_name"]).value
    rec = {"module": name, "start": now(), "thread": threading.current_thread().name}
    if os.environ.get("PROF_STACK"):
        import traceback

        rec["stack"] = [
            f"{f.filename.split('/mara_mjx/')[-1]}:{f.lineno} {f.name}"
            for f in traceback.extract_stack()
            if "mara_mjx" in f.filename
        ][-3:]
    _tls.rec = rec
    try:
        return _orig_cogc(backend, computation, *a, **k)
    finally:
        rec["end"] = now()
        PROGRAMS.append(rec)
        _tls.rec = None


compiler.compile_or_get_cached = cogc


def timed_into(field, orig):
    """`orig` with its seconds added to `field` of the program being compiled or loaded."""

    def wrapper(*a, **k):
        s = now()
        try:
            return orig(*a, **k)
        finally:
            r = getattr(_tls, "rec", None)
            if r is not None:
                r[field] = r.get(field, 0) + now() - s

    return wrapper


compiler._get_cache_key = timed_into("key_s", compiler._get_cache_key)


def get_exec(cache_key, compile_options, backend, executable_devices):
    r = getattr(_tls, "rec", None) or {}
    cache = cc._get_cache(backend)
    if cache is None:
        r["cache"] = "disabled"
        return None, None
    s = now()
    blob = cache.get(cache_key)
    r["read_s"] = now() - s
    if blob is None:
        r["cache"] = "miss"
        return None, None
    r["bytes"] = len(blob)
    s = now()
    blob = cc.decompress_executable(blob)
    r["decompress_s"] = now() - s
    ser, t = cc.extract_executable_and_time(blob)
    s = now()
    ex = backend.deserialize_executable(ser, executable_devices, compile_options)
    r["deserialize_s"] = now() - s
    r["cache"] = "hit"
    r["saved_compile_s"] = t / 1000 if t else t
    return ex, t


cc.get_executable_and_time = get_exec
compiler.backend_compile_and_load = timed_into("xla_compile_s", compiler.backend_compile_and_load)

# ---------------------------------------------------------------- the CLI's steps
import mara_mjx  # noqa: E402
from mara_mjx.ppo import checkpoint as ckpt  # noqa: E402
from mara_mjx.ppo import logger, trace_cache, warmup  # noqa: E402
from mara_mjx.runtime import runs  # noqa: E402

for attr in (
    "configure_jax",
    "resolve",
    "make_train",
    "run_meta",
    "train_loop",
    "finish",
    "check_finite",
    "make_evaluate",
    "_announce",
    "build_parser",
):
    patch(cli, attr, "cli." + attr)
patch(mara_mjx, "make", "mara_mjx.make (env build)")
patch(runs, "prepare_run_folder")
patch(runs, "write_json")
patch(runs, "prune_checkpoints")
patch(runs, "git_commit")
patch(runs, "versions")
patch(ckpt, "save_checkpoint")
patch(logger, "RunLogger")
patch(logger.RunLogger.__wrapped__, "log", "RunLogger.log")
patch(logger.RunLogger.__wrapped__, "close", "RunLogger.close")
patch(warmup, "start", "warmup.start")
patch(trace_cache, "key_material")
patch(trace_cache, "source_hash")
patch(trace_cache, "env_fingerprint")
patch(trace_cache, "_unpack")
patch(trace_cache, "exported_run")
patch(trace_cache, "exported_probe")
patch(jax.export, "deserialize", "jax.export.deserialize")
patch(jax, "device_get")
patch(jax, "eval_shape")
if BG:
    _start = warmup.start.__wrapped__

    def start_bg(*a, **k):
        k["min_cpus"] = 1
        return _start(*a, **k)

    warmup.start = timed("warmup.start", start_bg)
    _wait = warmup.Background.wait
    warmup.Background.wait = lambda self, stage=None: timed(f"wait {stage}", _wait)(self, stage)
_traced = warmup.traced


def traced(trainer, state, seed):
    t = _traced(trainer, state, seed)
    repl = {
        "init": timed("trainer.init call", t.init, True),
        "run": timed("trainer.run call", t.run, True),
    }
    if t.probe is not None:
        repl["probe"] = timed("trainer.probe call", t.probe, True)
    return t._replace(**repl)


warmup.traced = timed("warmup.traced", traced)

_main = cli.main


def main(argv=None):
    mark("main_start")
    try:
        return _main(argv)
    finally:
        mark("main_end")
        dump()
        import atexit

        atexit.register(lambda: open(OUT + ".exit0", "w").write(str(now())))  # runs first


def dump():
    new_mods = sorted(m for m in set(sys.modules) - MODS_AFTER_IMPORT if "." not in m)
    with open(OUT, "w") as f:
        json.dump(
            {
                "marks": MARKS,
                "events": EVENTS,
                "durations": DUR,
                "programs": PROGRAMS,
                "new_top_modules_after_import": new_mods,
                "heavy_loaded": {
                    m: m in sys.modules
                    for m in (
                        "matplotlib",
                        "tensorboardX",
                        "tensorboard",
                        "scipy",
                        "mujoco.mjx",
                        "flax",
                        "optax",
                        "tqdm",
                        "pandas",
                        "torch",
                        "tensorflow",
                        "orbax",
                        "chex",
                        "etils",
                    )
                },
            },
            f,
            indent=1,
        )


cli.main = main
sys.argv = ["mara_mjx.train", *ARGV]
from mara_mjx.runtime import distributed, supervise  # noqa: E402

sys.exit(supervise.run(lambda: distributed.run_cli(cli.main, cli.PROG), cli.PROG))
