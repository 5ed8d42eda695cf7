"""Determinism by construction: the ops XLA's GPU backend runs non-deterministically
without `--xla_gpu_deterministic_ops` are kept out of the programs that train.

On a GPU, a scatter that adds floating-point values (jnp's `.at[].add`, segment sums, the
gradient of a gather) and select-and-scatter sum in whatever order the threads' atomic
adds land, so the same seed can give other bits on every run. These checks read the
lowered StableHLO (traced and lowered here, not compiled, so they run on the CPU) of the
PPO update (the toy env's: `mara_mjx.ppo.train`'s SGD, GAE, networks) and of the MARA
env's batched step (MJX kinematics and collision) and list every scatter whose combiner
adds floats, or that may hit one index twice with different values. The GPU side (what the
flag costs, and whether runs agree bit for bit) is `benchmarks/determinism.py`.
"""

from __future__ import annotations

import re

import jax
from test_ppo import TOY_CONFIG, PointReach

from mara_mjx.ppo.train import make_train

FLOAT = re.compile(r"tensor<[0-9x]*(f16|bf16|f32|f64)>")


def unsafe_scatters(text: str) -> list[str]:
    """Scatters of a StableHLO module that XLA's GPU backend may run non-deterministically:
    a float combiner that is not a plain replacement (add, max, ...), or select-and-scatter.
    Integer adds (order-independent) and replacements are safe."""
    lines = text.splitlines()
    found = []
    for i, line in enumerate(lines):
        if "select_and_scatter" in line:
            found.append(line.strip())
        if '"stablehlo.scatter"' not in line:
            continue
        body, j = [], i + 1
        while not lines[j].lstrip().startswith("})"):
            body.append(lines[j])
            j += 1
        combines = any(re.search(r"stablehlo\.(add|multiply|maximum|minimum)", b) for b in body)
        if combines and FLOAT.search(lines[j].split("->")[-1]):
            found.append(line.strip()[:200] + " ... " + lines[j].strip()[-200:])
    return found


def test_the_checker_finds_a_float_scatter_add():
    def f(x, i):
        return x.at[i].add(1.0), x.at[i].set(2.0), (x > 0).astype(int).at[i].add(1)

    text = jax.jit(f).lower(jax.numpy.zeros(4), jax.numpy.array([0, 0])).as_text()
    assert len(unsafe_scatters(text)) == 1  # the float add; not the set, not the int add


def test_ppo_update_has_no_nondeterministic_scatter():
    trainer = make_train(PointReach(), TOY_CONFIG, updates_per_call=1)
    state = jax.eval_shape(trainer.init, jax.random.key(0))
    text = trainer.run.trace(state, 1).lower().as_text()
    assert '"stablehlo.scatter"' in text or "stablehlo.gather" in text  # it has indexing
    assert unsafe_scatters(text) == []


def test_env_step_has_no_nondeterministic_scatter(orient):
    env = orient.env
    keys = jax.random.split(jax.random.key(0), 2)
    states = jax.eval_shape(jax.vmap(env.reset), keys)
    actions = jax.ShapeDtypeStruct((2, env.action_size), jax.numpy.float32)
    text = jax.jit(jax.vmap(env.step)).trace(states, actions).lower().as_text()
    assert text.count('"stablehlo.scatter"') > 0  # MJX's kinematics scatter
    assert unsafe_scatters(text) == []
