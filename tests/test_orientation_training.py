"""Trainer-side orientation fixes (issue 11): the canonical quaternion reading, the
reward-hyperparameter curriculum's parsing, and the env-resolved config. Fast: no env step
is compiled."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mara_mjx
from mara_mjx.ppo.config import TrainConfig, for_env
from mara_mjx.ppo.curriculum import reward_curriculum
from mara_mjx.ppo.networks import RunningStats, canonical_quat, forward, make_network
from mara_mjx.ppo.presets import PRESETS
from mara_mjx.ppo.train import make_train


def test_canonical_quat_flips_only_negative_w():
    obs = jnp.arange(16.0).reshape(1, 16) * 0.1
    neg = obs.at[0, 9:13].set(jnp.array([-0.5, 0.5, -0.5, 0.5]))
    out = canonical_quat(neg, 9)
    np.testing.assert_allclose(out[0, 9:13], [0.5, -0.5, 0.5, -0.5])
    np.testing.assert_array_equal(out[0, :9], neg[0, :9])  # the rest untouched
    np.testing.assert_array_equal(out[0, 13:], neg[0, 13:])
    np.testing.assert_array_equal(canonical_quat(obs, 9), obs)  # w >= 0: unchanged
    np.testing.assert_array_equal(canonical_quat(neg, -1), neg)  # no quaternion block


def test_policy_reads_q_and_minus_q_alike():
    """q and -q are one rotation: with canonical_quat the networks cannot tell them apart,
    without it they do (so the test could fail)."""
    env = mara_mjx.make("MARAOrient")
    key = jax.random.key(0)
    obs = jax.random.normal(key, (5, 16))
    flipped = obs.at[:, 9:13].multiply(-1.0)
    stats = RunningStats.create(16)
    outputs = {}
    for on in (True, False):
        config = for_env(TrainConfig.of(canonical_quat=on, relative_actions=True), env)
        network = make_network(config, 6)
        params = network.init(jax.random.key(1), obs[0], obs[0])
        a = forward(network, params, stats, obs, 10.0)
        b = forward(network, params, stats, flipped, 10.0)
        outputs[on] = max(float(jnp.max(jnp.abs(x - y))) for x, y in zip(a, b, strict=True))
    assert outputs[True] == 0.0
    assert outputs[False] > 1e-6


def test_for_env_resolves_the_quaternion_block():
    orient, plain = mara_mjx.make("MARACollisionOrient"), mara_mjx.make("MARA")
    default = PRESETS["default"]
    assert default.policy.canonical_quat and default.policy.quat_index == -1
    assert for_env(default, orient).policy.quat_index == 9
    assert for_env(default, plain).policy.quat_index == -1
    assert for_env(default.replace(canonical_quat=False), orient).policy.quat_index == -1


def test_reward_curriculum_parses_and_names_bad_input():
    assert reward_curriculum("") == {}
    assert reward_curriculum("beta=0.5, gamma=0.02") == {"beta": 0.5, "gamma": 0.02}
    for bad, words in [
        ("bet=0.5", "alpha"),  # names the valid fields
        ("beta", "NAME=VALUE"),
        ("beta=x", "not a number"),
        ("beta=-1", ">= 0"),
        ("beta=nan", ">= 0"),
    ]:
        with pytest.raises(ValueError, match=words):
            reward_curriculum(bad)
    with pytest.raises(ValueError, match="train_reward"):
        TrainConfig.of(train_reward="delta=oops")
    with pytest.raises(ValueError, match="train_reward_until"):
        TrainConfig.of(train_reward_until=0.0)
    with pytest.raises(ValueError, match="train_collision_penalty"):
        TrainConfig.of(train_collision_penalty=-1.0)
    with pytest.raises(ValueError, match="bound_coef"):
        TrainConfig.of(bound_coef=float("inf"))


def test_train_reset_noise_starts_episodes_off_the_reset_pose():
    """train_reset_noise: the first episodes start within the noise box, not all at q = 0;
    an env without `reset_noise` in its params gets it cleared; bad values are named."""
    env = mara_mjx.make("MARA")
    sizes = dict(num_envs=8, num_steps=4, num_minibatches=1, total_timesteps=64)
    config = PRESETS["cpu"].replace(**sizes, train_reset_noise=0.3)
    state = make_train(env, config).init(jax.random.key(0))
    q = np.asarray(state.env_state.env_state.q)
    assert q.shape == (8, 6)
    assert np.abs(q).max() <= 0.3 + 1e-6
    assert np.abs(q).max() > 0.1  # noise drawn (uniform in +-0.3 on 48 values)
    np.testing.assert_allclose(state.env_state.env_state.params.reset_noise, 0.3)
    off = make_train(env, config.replace(train_reset_noise=0.0)).init(jax.random.key(0))
    np.testing.assert_array_equal(off.env_state.env_state.q, 0.0)
    with pytest.raises(ValueError, match="train_reset_noise"):
        TrainConfig.of(train_reset_noise=0.6)

    class NoNoise:  # a user's env whose params have no reset_noise
        default_params = object()

    assert for_env(config, NoNoise()).curriculum.train_reset_noise == 0.0


def test_a_held_train_reset_noise_is_the_env_flag_s_noise_at_every_update():
    """train_reset_noise_final = train_reset_noise: every rollout's episodes start with
    that noise, bit for bit the value the env's own `--reset_noise 0.02` gives them
    (which evaluation overrides); left at -1 it shrinks to the env's own (0)."""
    from mara_mjx.envs.batched import BatchedEnv
    from mara_mjx.ppo.curriculum import make_schedule

    env = mara_mjx.make("MARA")
    flag = mara_mjx.make("MARA", reset_noise=0.02).default_params.reset_noise
    sizes = dict(num_envs=8, num_steps=4, num_minibatches=1, total_timesteps=64)
    config = PRESETS["cpu"].replace(**sizes, train_reset_noise=0.02)
    state = make_train(env, config).init(jax.random.key(0)).env_state
    benv = BatchedEnv(env, 8)
    for final, last in ((0.02, flag), (-1.0, 0.0)):
        curriculum = config.replace(train_reset_noise_final=final).curriculum
        schedule = make_schedule(curriculum, env, benv, num_updates=10)
        noise = [
            np.asarray(schedule.rollout_state(state, jnp.int32(u)).env_state.params.reset_noise)
            for u in (0, 3, 10)
        ]
        np.testing.assert_array_equal(noise[0], flag)  # 0.02 at the start either way
        np.testing.assert_array_equal(noise[-1], last)
        if final > 0:
            np.testing.assert_array_equal(noise[1], flag)
        else:
            assert 0.0 < noise[1].max() < flag
        np.testing.assert_array_equal(schedule.initial_params().reset_noise, flag)
    with pytest.raises(ValueError, match="train_reset_noise_final"):
        TrainConfig.of(train_reset_noise=0.02, train_reset_noise_final=0.7)


def test_stagger_episodes_spreads_the_first_episodes_over_the_horizon():
    """stagger_episodes: the envs' step counters start spread over [0, horizon), so
    their episodes end at different updates; off, all start at 0 (the same key stream)."""
    env = mara_mjx.make("MARA", max_episode_steps=64)
    sizes = dict(num_envs=32, num_steps=4, num_minibatches=1, total_timesteps=128)
    config = PRESETS["cpu"].replace(**sizes)
    on = make_train(env, config.replace(stagger_episodes=True)).init(jax.random.key(0))
    steps = np.asarray(on.env_state.env_state.step)
    assert steps.min() >= 0 and steps.max() < 64
    assert len(np.unique(steps)) > 8  # spread, not one phase
    off = make_train(env, config).init(jax.random.key(0))
    np.testing.assert_array_equal(off.env_state.env_state.step, 0)
    np.testing.assert_array_equal(off.env_state.env_state.q, on.env_state.env_state.q)
