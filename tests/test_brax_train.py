"""brax's own PPO (`brax.training.agents.ppo.train.train`, its evaluator on) on the brax
adapter, as the adapter's docstring shows a user calling it (issue 34, item 14).

With brax 0.14.2 and JAX 0.10 it failed twice: `jax.device_put_replicated` (removed
from JAX, called by brax) and then, in brax's evaluator, a scan whose carried
`State.metrics` gained brax's `reward` key at reset and lost it in the adapter's step.
Tiny settings (one training epoch between two evaluations): the test is what compiles.
"""

from __future__ import annotations

import math
import subprocess
import sys

import jax
import pytest

pytest.importorskip("brax")

from brax.envs.wrappers.training import EvalWrapper, wrap  # noqa: E402
from brax.training.agents.ppo import train as ppo  # noqa: E402

from mara_mjx.adapters import brax_env  # noqa: E402
from mara_mjx.adapters.brax_env import METRICS, make_brax_env  # noqa: E402

EPISODE = 8


def test_brax_ppo_train_with_its_evaluator_runs_on_the_adapter():
    env = make_brax_env("MARA", episode_length=EPISODE)
    progress = []
    make_policy, params, metrics = ppo.train(
        environment=env,
        num_timesteps=64,
        episode_length=EPISODE,
        num_envs=4,
        batch_size=4,
        num_minibatches=2,
        unroll_length=4,
        num_updates_per_batch=1,
        num_evals=2,
        num_eval_envs=2,
        seed=0,
        progress_fn=lambda step, m: progress.append((int(step), dict(m))),
    )
    assert [step for step, _ in progress] == [0, 64]
    for _, m in progress:
        assert math.isfinite(float(m["eval/episode_reward"]))
        assert {f"eval/episode_{k}" for k in METRICS} <= set(m)
    assert float(progress[-1][1]["eval/avg_episode_length"]) == EPISODE
    obs = jax.numpy.zeros(env.observation_size)
    action, _ = make_policy(params, deterministic=True)(obs, jax.random.PRNGKey(0))
    assert action.shape == (env.action_size,)


def test_metrics_keys_are_kept_from_reset_on():
    """The mechanism: a key a wrapper adds to the reset state's metrics (brax's
    EvalWrapper adds `reward`) is still there after the adapter's step, and JAX's
    drop-in `device_put_replicated` is in place (brax's ppo.train calls it)."""
    env = EvalWrapper(wrap(make_brax_env("MARA"), episode_length=EPISODE))
    state = jax.eval_shape(env.reset, jax.random.split(jax.random.PRNGKey(0), 2))
    action = jax.ShapeDtypeStruct((2, 6), jax.numpy.float32)
    after = jax.eval_shape(env.step, state, action)
    assert set(state.metrics) == set(after.metrics) == {*METRICS, "reward"}
    assert jax.device_put_replicated is brax_env.device_put_replicated or (
        "device_put_replicated" in vars(jax)
    )
    x = jax.device_put_replicated({"a": jax.numpy.arange(3)}, jax.local_devices()[:1])
    assert x["a"].shape == (1, 3)


QUIET = """
from mara_mjx.bench.brax_peer import brax_kwargs
from mara_mjx.ppo import PRESETS
brax_kwargs(PRESETS["default"].ppo, 16)  # imports brax's PPO networks
import mara_mjx.adapters.brax_env
"""


def test_our_brax_imports_are_quiet():
    """brax imports mujoco.mjx, which prints "Failed to import warp" and "Failed to import
    mujoco_warp" (its optional Warp backend) on stdout: where our code imports brax,
    mujoco.mjx is imported quietly first (the benchmark's brax study printed both)."""
    proc = subprocess.run(
        [sys.executable, "-c", QUIET], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Failed to import" not in proc.stdout + proc.stderr, proc.stdout
