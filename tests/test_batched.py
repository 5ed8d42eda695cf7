"""BatchedEnv: vmap + auto-reset + episode statistics."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import max_traces

import mara_mjx
from mara_mjx import BatchedEnv

N = 3
REACH = jnp.array([1.3338, -1.5341, -0.7833, 0.0, 2.3903, -0.237])


@pytest.fixture(scope="module")
def batched():
    env = mara_mjx.make("MARA", max_episode_steps=2, reset_noise=0.2)
    benv = BatchedEnv(env, N)
    return env, benv, jax.jit(max_traces(benv.reset)), jax.jit(max_traces(benv.step))


def test_auto_reset_keeps_final_obs_and_episode_statistics(batched):
    env, benv, reset, step = batched
    s0 = reset(jax.random.key(0))
    q0 = np.asarray(s0.env_state.q)
    assert np.all(np.abs(q0) <= 0.2) and len({tuple(r) for r in q0.round(6)}) == N
    actions = jnp.stack([REACH, REACH + 0.05, jnp.array([0.0, 2.0, 0, 0, 0, 0])])  # env 2 collides
    s1 = step(s0, actions)
    assert not np.any(np.asarray(s1.done))
    np.testing.assert_allclose(np.asarray(s1.final_obs), np.asarray(s1.obs))
    s2 = step(s1, actions)
    assert np.all(np.asarray(s2.truncated)) and not np.any(np.asarray(s2.terminated))
    # final_obs is the pre-reset observation: the commanded pose
    np.testing.assert_allclose(np.asarray(s2.final_obs[:, :6]), np.asarray(actions), atol=1e-6)
    # obs is a fresh reset: a new random pose, not the first reset's one
    q_new = np.asarray(s2.obs[:, :6])
    assert np.all(np.abs(q_new) <= 0.2)
    assert not np.allclose(q_new, q0)
    np.testing.assert_array_equal(np.asarray(s2.env_state.step), 0)
    np.testing.assert_allclose(np.asarray(s2.episode_length), 2.0)
    expected_return = np.asarray(s1.reward) + np.asarray(s2.reward)
    np.testing.assert_allclose(np.asarray(s2.episode_return), expected_return, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(s2.episode_collisions), [0.0, 0.0, 2.0])
    # mid-episode steps report no finished episode
    np.testing.assert_allclose(np.asarray(s1.episode_return), 0.0)
    # the new episode's running statistics start over
    np.testing.assert_allclose(np.asarray(s2.env_state.metrics["episode_return"]), 0.0)


def test_per_env_params_and_errors(batched):
    env, benv, reset, step = batched
    p = env.make_params(target_pos=(0.3, 0.2, 1.0))
    rows = jax.tree.map(lambda a, b: jnp.stack([a, b, a]), env.default_params, p)
    s = benv.reset(jax.random.key(0), rows)
    np.testing.assert_allclose(np.asarray(s.env_state.params.target_pos[1]), [0.3, 0.2, 1.0])
    e = np.asarray(s.obs[:, 6:9])
    assert np.abs(e[0] - e[1]).max() > 0.3  # a target ~0.7 m away from the default one
    with pytest.raises(ValueError, match="expected 3"):
        benv.reset(jax.random.key(0), jax.tree.map(lambda x: x[:2], rows))
    with pytest.raises(ValueError, match=r"action must have shape \(3, 6\)"):
        benv.step(s, jnp.zeros((2, 6)))
    with pytest.raises(ValueError, match="num_envs"):
        BatchedEnv(env, 0)
    with pytest.raises(ValueError, match="reset_strategy"):
        BatchedEnv(env, 2, reset_strategy="cached")


def _bits(x) -> np.ndarray:
    """A leaf as a numpy array (a typed PRNG key as its key data)."""
    return np.asarray(jax.random.key_data(x) if jnp.issubdtype(x.dtype, jax.dtypes.prng_key) else x)


def test_the_cond_reset_gives_the_select_reset_s_bits(batched):
    # reset_strategy="cond" runs the resets only on steps where an episode ended; it must
    # select the same values as "select" (the default), across episode ends and collisions
    env, benv, reset, step = batched
    cond_step = jax.jit(BatchedEnv(env, N, reset_strategy="cond").step)
    a = b = reset(jax.random.key(3))
    actions = jax.random.uniform(jax.random.key(4), (5, N, 6), minval=-2.0, maxval=2.0)
    ended = 0
    for act in actions:
        a, b = step(a, act), cond_step(b, act)
        ended += int(np.asarray(a.done).sum())
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            np.testing.assert_array_equal(_bits(x), _bits(y))
    assert ended >= 2 * N  # the 2-step episodes ended twice per env
