"""The train CLI's background compile (mara_mjx.ppo.warmup): after it, the first
`trainer.run` call compiles nothing (the same executable serves it), nor does the first
call of the reach probe kept apart from `run` (compiled in its own thread beside it)."""

from __future__ import annotations

import jax
from test_ppo import TOY_CONFIG, PointReach

from mara_mjx.ppo import warmup
from mara_mjx.ppo.train import make_train


def test_first_run_call_uses_the_background_compile(compiled):
    config = TOY_CONFIG.replace(probe_reach_steps=2)
    trainer = make_train(PointReach(), config, updates_per_call=2, probe_apart=True)
    key = jax.random.key(0)
    background = warmup.start(trainer, key, min_cpus=1)
    assert background is not None  # one CPU device
    state = trainer.init(key)
    background.wait("run")
    background.wait("probe")
    background.wait()
    assert background.error is None
    assert any("run" in name for name in compiled)  # compiled in the background
    assert any("lambda" in name for name in compiled), compiled  # the probe, beside it
    compiled.clear()
    after, metrics = trainer.run(state, 2)
    reach = trainer.probe(after, 2)
    assert not compiled, compiled
    assert bool(metrics["valid"].all()) and float(reach[1]) > 0.0
