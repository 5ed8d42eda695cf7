"""Compile in the background what the train CLI calls later, to shorten its start-up.

Before the first PPO update the train CLI used to compile, one after the other,
`trainer.init` and then `trainer.run`; after training, the final evaluation. XLA
compiles with Python's GIL released, so two compiles in two threads overlap on a machine
with spare cores (a GPU host has many):

* `trainer.run` is lowered and compiled for the state `trainer.init` will return (its
  shapes from `jax.eval_shape`; one device) while the main thread
  compiles and runs `init`; the first `trainer.run(state, n)` call then finds the
  executable in the jitted function's cache (no second compile);
* the reach probe (`Trainer.probe`, where make_train keeps it apart from `run`) in a
  second thread beside `run`: the two programs compile at once instead of as one;
* then the evaluation rollout is compiled, for a policy of the final one's shapes,
  while training runs.

Both only fill caches: the results do not depend on them, and a failed or unfinished
background compile leaves the later call to compile as before (`benchmarks/NOTES.md`,
start-up section, has the measured seconds).
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable
from typing import Any

import jax


class Background:
    """A daemon thread running `fn(done)`, where `done(stage)` marks a stage finished;
    `wait(stage)` blocks until it is (or the thread ended), `wait()` joins the thread.
    An exception is printed as one line and dropped: the foreground call it was
    preparing compiles by itself instead."""

    def __init__(self, what: str, fn: Callable[[Callable[[str], None]], Any]):
        self.what = what
        self.error: BaseException | None = None
        self._stages: dict[str, threading.Event] = {}
        self._lock = threading.Lock()

        def target() -> None:
            try:
                fn(lambda stage: self._event(stage).set())
            except Exception as e:  # a cache warm-up must never stop training
                self.error = e
                print(f"mara_mjx: background compile of {what} failed: {e}", file=sys.stderr)

        self.thread = threading.Thread(target=target, name=f"compile {what}", daemon=True)
        self.thread.start()

    def _event(self, stage: str) -> threading.Event:
        with self._lock:
            return self._stages.setdefault(stage, threading.Event())

    def wait(self, stage: str | None = None) -> None:
        if stage is None:
            self.thread.join()
            return
        event = self._event(stage)
        while not event.wait(0.1) and self.thread.is_alive():
            pass


def start(
    trainer: Any,
    key: jax.Array,
    evaluate_fn: Any = None,
    make_policy: Any = None,
    min_cpus: int = 4,
) -> Background | None:
    """In one background thread: compile `trainer.run(state, n)` (n a Python int) for
    `state = trainer.init(key)` (stage "run": call `wait("run")` before the first
    `trainer.run`, so that it does not start a second compile of its own), beside it in a
    second thread `trainer.probe` where the trainer has one (stage "probe", likewise),
    then, if given, the jitted `evaluate_fn(policy)`
    (`mara_mjx.ppo.evaluation.make_evaluate`) for `policy = make_policy(state)`. Only on
    one device (None otherwise: where a sharded state lives is what `init` decides, and a
    guess that differs would compile twice), and with at least `min_cpus` CPU cores (on
    2 cores the two compiles share them and the background trace fights the foreground
    for the GIL: measured slower, benchmarks/NOTES.md section 13)."""
    if trainer.env.mesh is not None or jax.device_count() != 1:
        return None
    if (os.cpu_count() or 1) < min_cpus:
        return None

    def compile_all(done: Callable[[str], None]) -> None:
        # init's own shapes, with the sharding its outputs have (none: uncommitted; the
        # device: `traced`'s init), so the cache key is the later call's
        state = jax.eval_shape(trainer.init, key)
        n = jax.ShapeDtypeStruct((), jax.numpy.int32, weak_type=True)  # a Python int
        probe = None
        if trainer.probe is None:
            done("probe")
        else:  # the reach probe's own program, compiled beside run's (a third thread)
            probe = Background("the reach probe", lambda _: _compile_probe(trainer, state, n, done))
        trainer.run.lower(state, n).compile()
        done("run")
        if probe is not None:
            probe.wait()
        if evaluate_fn is not None:
            evaluate_fn.lower(make_policy(state)).compile()

    return Background("trainer.run and the evaluation", compile_all)


def _compile_probe(trainer: Any, state: Any, n: Any, done: Callable[[str], None]) -> None:
    try:
        trainer.probe.lower(state, n).compile()
    finally:  # compiled or not, the first call may go ahead (and compile what is missing)
        done("probe")


def traced(trainer: Any, state: Any, seed: int) -> Any:
    """`trainer` with its `run` (and its reach probe, where kept apart) replaced by the
    exported programs that mara_mjx.ppo.trace_cache keeps beside the compilation cache
    (loaded on a warm start: no tracing), for `state` or, when None, the state
    `trainer.init(key(seed))` returns. Prints where the programs came from; unchanged
    where the cache is off."""
    from mara_mjx.ppo import trace_cache

    folder = trace_cache.cache_folder()
    if folder is None or trainer.env.mesh is not None or jax.device_count() != 1:
        return trainer  # (several devices: as `start`)
    # init's state on the device as the exported run's (committed): `start`'s background
    # compiles then lower for the arrays training passes (no second compile)
    init = jax.jit(trainer.init, out_shardings=trace_cache.device_sharding())
    shapes = jax.eval_shape(init, jax.random.key(seed)) if state is None else state
    run, status = trace_cache.exported_run(trainer, shapes, folder)
    print(f"mara_mjx: training program {status}", flush=True)
    if run is trainer.run:
        return trainer
    probe = trainer.probe
    if probe is not None:  # kept apart from run (make_train's probe_apart): kept alike
        probe, status = trace_cache.exported_probe(trainer, shapes, folder)
        print(f"mara_mjx: reach probe {status}", flush=True)
    return trainer._replace(init=init, run=run, probe=probe)
