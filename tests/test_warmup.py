"""The train CLI's background compile (mara_mjx.ppo.warmup): after it, the first
`trainer.run` call compiles nothing (the same executable serves it)."""

from __future__ import annotations

import jax
from test_ppo import TOY_CONFIG, PointReach

from mara_mjx.ppo import warmup
from mara_mjx.ppo.train import make_train


def test_first_run_call_uses_the_background_compile(compiled):
    trainer = make_train(PointReach(), TOY_CONFIG, updates_per_call=2)
    key = jax.random.key(0)
    background = warmup.start(trainer, key, min_cpus=1)
    assert background is not None  # one CPU device
    state = trainer.init(key)
    background.wait("run")
    background.wait()
    assert background.error is None
    assert any("run" in name for name in compiled)  # compiled in the background
    compiled.clear()
    after, metrics = trainer.run(state, 2)
    assert not [name for name in compiled if "run" in name], compiled
    assert bool(metrics["valid"].all())
