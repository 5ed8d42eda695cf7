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

import os
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


def test_env_step_has_no_nondeterministic_scatter():
    """The train driver's step through MJX (its kinematics scatter, safely) and through the
    default lean pass (no scatter at all)."""
    import mara_mjx

    for kinematics, scatters in (("mjx", True), ("lean", False)):
        env = mara_mjx.make("MARACollisionOrient", kinematics=kinematics)
        keys = jax.random.split(jax.random.key(0), 2)
        states = jax.eval_shape(jax.vmap(env.reset), keys)
        actions = jax.ShapeDtypeStruct((2, env.action_size), jax.numpy.float32)
        text = jax.jit(jax.vmap(env.step)).trace(states, actions).lower().as_text()
        assert (text.count('"stablehlo.scatter"') > 0) == scatters
        assert unsafe_scatters(text) == []


def test_real_driver_scatters_only_through_mjx_dynamics():
    """The real driver's default step (contacts detected, the plain-jnp dynamics of
    envs/dynamics.py) has no non-deterministic scatter; through MJX's dynamics (mjx.step:
    real_contacts='physical', or kinematics='mjx') it sums floats with scatter-adds. The
    CLIs still add `--xla_gpu_deterministic_ops` for every real-driver run
    (cli.reproducible_gpu_flags): a run may use MJX's dynamics, and the default's
    reproducibility without the flag is not yet measured on a GPU."""
    import mara_mjx

    for overrides, unsafe in (
        ({}, False),
        ({"randomize": True}, False),
        ({"real_contacts": "physical"}, True),
        ({"kinematics": "mjx"}, True),
    ):
        env = mara_mjx.make("MARA", driver="real", **overrides)
        keys = jax.random.split(jax.random.key(0), 2)
        states = jax.eval_shape(jax.vmap(env.reset), keys)
        actions = jax.ShapeDtypeStruct((2, env.action_size), jax.numpy.float32)
        text = jax.jit(jax.vmap(env.step)).trace(states, actions).lower().as_text()
        assert (unsafe_scatters(text) != []) == unsafe, overrides


def test_the_clis_choose_reproducible_gpu_flags_by_driver(tmp_path, monkeypatch):
    """Train-driver runs get deterministic compiles (no autotuning) instead of XLA's
    deterministic ops, real-driver runs (the flag, or a checkpoint trained with it) keep
    the deterministic ops, and flags the user set in XLA_FLAGS are left alone."""
    import argparse

    from mara_mjx.cli import common as cli
    from mara_mjx.ppo import checkpoint as ckpt

    assert cli.reproducible_gpu_flags(False) == "--xla_gpu_autotune_level=0"
    assert cli.reproducible_gpu_flags(True) == "--xla_gpu_deterministic_ops=true"
    plain = argparse.Namespace(**{"env.max_episode_steps": 16})
    assert not cli.uses_real_driver(plain)
    assert cli.uses_real_driver(argparse.Namespace(**{"env.driver": "real"}))
    assert not cli.uses_real_driver(argparse.Namespace(**{"env.driver": "train"}), "x")
    assert cli.uses_real_driver(plain, str(tmp_path / "missing"))  # unreadable: careful
    monkeypatch.setattr(ckpt, "find_checkpoint", lambda p: p)
    for driver in ("train", "real"):  # a checkpoint's env config decides without the flag
        meta = {"env_config": {"driver": driver}}
        monkeypatch.setattr(ckpt, "load_checkpoint", lambda p, m=meta: ({}, m))
        assert cli.uses_real_driver(plain, "ckpt.npz") == (driver == "real")
    monkeypatch.setenv("MARA_MJX_COMPILATION_CACHE", "0")
    for given, real, expected in (
        ("--xla_cpu_foo=1", False, "--xla_cpu_foo=1 --xla_gpu_autotune_level=0"),
        ("", True, "--xla_gpu_deterministic_ops=true"),
        ("--xla_gpu_deterministic_ops=false", False, "--xla_gpu_deterministic_ops=false"),
        ("--xla_gpu_autotune_level=4", True, "--xla_gpu_autotune_level=4"),
    ):
        monkeypatch.setenv("XLA_FLAGS", given)
        cli.configure_jax(None, real_driver=real)
        assert os.environ["XLA_FLAGS"] == expected
