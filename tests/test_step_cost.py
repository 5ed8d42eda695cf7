"""The lean train-driver step as the PPO rollout runs it (BatchedEnv, auto-reset) against a
plain reference (the step benchmarks/step_cost.py measures)."""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import mara_mjx
from mara_mjx.envs.batched import BatchedEnv

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from lean_check import c_mujoco  # noqa: E402

N, T, HORIZON = 3, 11, 4  # envs, steps, episode length: two auto-resets per env


def test_batched_lean_step_matches_one_env_at_a_time_across_auto_resets():
    """BatchedEnv.step over episodes of 4 steps with reset noise (so every auto-reset
    draws a new pose from the env's key): the same keys, step counters, done flags and
    collided flags as stepping each env alone with `env.step` and resetting it by hand
    (key, reset_key = split(key); reset(reset_key)), and observations, final
    observations and rewards within float32 rounding. Actions within 1e-4 m of contact
    (C MuJoCo) are replaced by the zero pose, where the two may round apart."""
    env = mara_mjx.make("MARACollisionOrient", max_episode_steps=HORIZON, reset_noise=0.1)
    rng = np.random.default_rng(5)
    actions = rng.uniform(env.joint_lower, env.joint_upper, (T, N, 6)).astype(np.float32)
    _, dist = c_mujoco(env.arm.mj_model, actions.reshape(-1, 6))
    actions[(np.abs(dist) < 1e-4).reshape(T, N)] = 0.0

    benv = BatchedEnv(env, N, devices=1)
    keys = jax.random.split(jax.random.key(11), N)

    def rollout(keys):
        def body(state, a):
            state = benv.step(state, a)
            inner = state.env_state
            out = (state.obs, state.final_obs, state.reward, state.done)
            return state, (
                *out,
                state.metrics["collided"],
                inner.step,
                jax.random.key_data(inner.key),
            )

        return jax.lax.scan(body, benv.reset(keys), jnp.asarray(actions))[1]

    got = [np.asarray(x) for x in jax.jit(rollout)(keys)]

    reset, step = jax.jit(env.reset), jax.jit(env.step)
    want = [[] for _ in got]
    for i in range(N):
        s = reset(keys[i])
        for t in range(T):
            s = step(s, actions[t, i])
            final, done = s.obs, bool(s.terminated | s.truncated)
            row = [None, final, s.reward, done, s.metrics["collided"]]
            if done:
                key, reset_key = jax.random.split(s.key)
                s = reset(reset_key).replace(key=key)
            row[0] = s.obs
            row += [s.step, jax.random.key_data(s.key)]
            for k, v in enumerate(row):
                want[k].append(np.asarray(v))
    want = [np.stack(w).reshape((N, T) + np.shape(w[0])).swapaxes(0, 1) for w in want]

    obs, final_obs, reward, done, collided, steps, key_data = range(7)
    assert want[done].sum() == N * (T // HORIZON)  # the rollout crosses resets
    assert 0 < want[collided].sum() < N * T  # and collides
    for k in (done, collided, steps, key_data):
        np.testing.assert_array_equal(got[k], want[k])
    for k in (obs, final_obs, reward):
        np.testing.assert_allclose(got[k], want[k], rtol=1e-6, atol=1e-6)
