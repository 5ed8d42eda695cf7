"""PPO pieces against references, and PPO learning a tiny pure-jnp task (CPU, seconds).

The toy env and its trainer are built and compiled once per session.
"""

from __future__ import annotations

import argparse
import functools
import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import mara_mjx
from mara_mjx.cli.common import Section, add_flags, overrides
from mara_mjx.envs.base import EnvConfig
from mara_mjx.envs.randomize import RandomizeConfig
from mara_mjx.envs.rewards import RewardParams
from mara_mjx.ppo import (
    PRESETS,
    EvalConfig,
    PPOConfig,
    RunConfig,
    RunningStats,
    gae,
    gaussian_entropy,
    gaussian_log_prob,
    make_lr_schedule,
    make_policy,
    make_train,
    ppo_loss,
    update_stats,
)
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.config import TrainConfig
from mara_mjx.ppo.networks import forward, make_network
from mara_mjx.ppo.optim import stratified_minibatches

# --------------------------------------------------------------------------- toy env


@struct.dataclass
class ToyParams:
    target: jax.Array  # (3,) m


@struct.dataclass
class ToyState:
    pos: jax.Array  # (3,) m
    obs: jax.Array  # (6,) pos, pos - target
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    step: jax.Array
    key: jax.Array
    params: ToyParams
    metrics: dict[str, jax.Array]


class PointReach:
    """A point that teleports to the commanded position (like the MARA train driver).

    Observation (6,): position (m), position - target (m). Action (3,): absolute target
    position (m). Reward: -5 * RMS distance to the target. Reset: uniform in [-1, 1]^3.
    Truncates after `horizon` steps; terminates if a coordinate leaves [-4, 4] m (so that
    GAE sees both kinds of episode end).
    """

    observation_size = 6
    action_size = 3

    def __init__(self, horizon: int = 8):
        self.max_episode_steps = horizon
        self.default_params = ToyParams(target=jnp.array([0.6, -0.4, 0.3]))

    def make_params(self, reset_noise: float = 0.0) -> ToyParams:
        return self.default_params

    def _observe(self, pos, params):
        return jnp.concatenate([pos, pos - params.target])

    def reset(self, key: jax.Array, params: ToyParams | None = None) -> ToyState:
        params = self.default_params if params is None else params
        key, pos_key = jax.random.split(key)
        pos = jax.random.uniform(pos_key, (3,), minval=-1.0, maxval=1.0)
        zero = jnp.zeros(())
        err = jnp.abs(pos - params.target)
        return ToyState(
            pos=pos,
            obs=self._observe(pos, params),
            reward=zero,
            terminated=jnp.array(False),
            truncated=jnp.array(False),
            step=jnp.zeros((), jnp.int32),
            key=key,
            params=params,
            metrics={
                "distance": jnp.sqrt(jnp.mean(err**2)),
                "position_error": err,
                "collided": zero,
                "collisions": zero,
                "nonfinite_actions": zero,
                "episode_return": zero,
                "episode_length": zero,
            },
        )

    def step(self, state: ToyState, action: jax.Array) -> ToyState:
        pos = action
        err = jnp.abs(pos - state.params.target)
        distance = jnp.sqrt(jnp.mean(err**2))
        reward = -5.0 * distance
        step = state.step + 1
        m = state.metrics
        return state.replace(
            pos=pos,
            obs=self._observe(pos, state.params),
            reward=reward,
            terminated=jnp.any(jnp.abs(pos) > 4.0),
            truncated=step >= self.max_episode_steps,
            step=step,
            metrics={
                **m,
                "distance": distance,
                "position_error": err,
                "episode_return": m["episode_return"] + reward,
                "episode_length": step.astype(jnp.float32),
            },
        )


TOY_CONFIG = TrainConfig.of(
    num_envs=16,
    num_steps=16,
    total_timesteps=16 * 16 * 40,
    num_minibatches=4,
    update_epochs=4,
    learning_rate=1e-2,
    lr_schedule="constant",
    hidden_sizes=(32, 32),
    normalize_obs=True,
)


@pytest.fixture(scope="session")
def toy():
    """The toy trainer (4 updates per call) and its initial state."""
    trainer = make_train(PointReach(), TOY_CONFIG, updates_per_call=4)
    state = trainer.init(jax.random.key(0))
    return trainer, state


@pytest.fixture(scope="session")
def toy_history(toy):
    """All 40 toy updates: final state and metrics (numpy, one row per update)."""
    trainer, state = toy
    rows = []
    for _ in range(trainer.num_updates // trainer.updates_per_call):
        state, metrics = trainer.run(state, trainer.updates_per_call)
        rows.append(jax.device_get(metrics))
    history = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    return state, history


# ----------------------------------------------------------------------------- GAE


def reference_gae(reward, value, final_value, terminated, truncated, gamma, lam):
    """GAE as CleanRL writes it, plus the truncation bootstrap: at truncated steps the
    reward gets gamma * V(final_obs); otherwise a step bootstraps from V(obs[t+1]) (and
    from V(final_obs) past the last step); an episode end cuts the recursion."""
    T, N = reward.shape
    adv = np.zeros((T, N))
    for n in range(N):
        running = 0.0
        for t in reversed(range(T)):
            done = terminated[t, n] or truncated[t, n]
            r = reward[t, n]
            if truncated[t, n] and not terminated[t, n]:
                r = r + gamma * final_value[t, n]
            if done:
                next_v = 0.0
            elif t == T - 1:
                next_v = final_value[t, n]
            else:
                next_v = value[t + 1, n]
            delta = r + gamma * next_v - value[t, n]
            running = delta + gamma * lam * (0.0 if done else 1.0) * running
            adv[t, n] = running
    return adv


def test_gae_matches_python_loop():
    rng = np.random.default_rng(0)
    T, N, gamma, lam = 23, 5, 0.97, 0.9
    reward = rng.normal(size=(T, N))
    value = rng.normal(size=(T, N))
    final_value = rng.normal(size=(T, N))
    terminated = rng.random((T, N)) < 0.08
    truncated = rng.random((T, N)) < 0.15
    truncated[-1, 0] = True
    terminated[-1, 1] = truncated[-1, 1] = True
    assert terminated.any() and truncated.any() and (terminated & truncated).any()
    done = terminated | truncated
    # Without an episode end, final_obs[t] is obs[t + 1] (BatchedEnv's contract).
    for t in range(T - 1):
        final_value[t] = np.where(done[t], final_value[t], value[t + 1])

    expected = reference_gae(reward, value, final_value, terminated, truncated, gamma, lam)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    next_value = f32(final_value) * (1.0 - f32(terminated))
    adv, returns = jax.jit(gae, static_argnums=(4, 5))(
        f32(reward), f32(value), next_value, jnp.asarray(done), gamma, lam
    )
    np.testing.assert_allclose(adv, expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(returns, expected + value, rtol=1e-5, atol=1e-5)


# ----------------------------------------------------------------------------- loss


def test_ppo_loss_hand_computed():
    # ratio = exp(log_prob - old) = (1.5, 0.5); advantages (3, 1) normalise to (1, -1)
    # (population std 1); clip 0.2:
    #   policy: max(-1 * 1.5, -1 * 1.2) = -1.2 ; max(0.5, 0.8) = 0.8 -> mean -0.2
    #   value (clipped, eps 0.2): v = (1, 0), v_old = (0.5, 0.5), R = (2, 0)
    #     sample 1: (1 - 2)^2 = 1 ; v_clip = 0.5 + 0.2 = 0.7 -> 1.69 ; max 1.69
    #     sample 2: 0 ; v_clip = 0.5 - 0.2 = 0.3 -> 0.09 ; max 0.09
    #     value = 0.5 * (1.69 + 0.09) / 2 = 0.445
    #   entropy mean 1.5; total = -0.2 + 0.5 * 0.445 - 0.01 * 1.5 = 0.0075
    #   approx_kl = 0.5 * (log(1.5)^2 + log(0.5)^2) / 2 ; clip_frac = 1
    total, info = ppo_loss(
        log_prob=jnp.log(jnp.array([1.5, 0.5])),
        value=jnp.array([1.0, 0.0]),
        entropy=jnp.array([1.0, 2.0]),
        old_log_prob=jnp.zeros(2),
        old_value=jnp.array([0.5, 0.5]),
        advantages=jnp.array([3.0, 1.0]),
        returns=jnp.array([2.0, 0.0]),
        clip_eps=0.2,
        vf_coef=0.5,
        ent_coef=0.01,
    )
    np.testing.assert_allclose(info.policy, -0.2, atol=1e-6)
    np.testing.assert_allclose(info.value, 0.445, atol=1e-6)
    np.testing.assert_allclose(info.entropy, 1.5, atol=1e-6)
    np.testing.assert_allclose(total, 0.0075, atol=1e-6)
    kl = 0.5 * (math.log(1.5) ** 2 + math.log(0.5) ** 2) / 2
    np.testing.assert_allclose(info.approx_kl, kl, rtol=1e-5)
    np.testing.assert_allclose(info.clip_frac, 1.0)

    # Unclipped value loss and raw advantages: policy = mean(-3 * 1.2, -1 * 0.5) = -2.05
    # (sample 2 has A > 0 and ratio 0.5 < 0.8: the unclipped -0.5 is larger than -0.8),
    # value = 0.5 * (1 + 0) / 2 = 0.25.
    _, info = ppo_loss(
        jnp.log(jnp.array([1.5, 0.5])),
        jnp.array([1.0, 0.0]),
        jnp.array([1.0, 2.0]),
        jnp.zeros(2),
        jnp.array([0.5, 0.5]),
        jnp.array([3.0, 1.0]),
        jnp.array([2.0, 0.0]),
        clip_eps=0.2,
        vf_coef=0.5,
        ent_coef=0.0,
        clip_value=False,
        normalize_advantages=False,
    )
    np.testing.assert_allclose(info.policy, -2.05, atol=1e-6)
    np.testing.assert_allclose(info.value, 0.25, atol=1e-6)


@pytest.mark.parametrize("steps, envs, minibatches", [(8, 6, 4), (4, 6, 8), (6, 4, 4)])
def test_stratified_minibatches_partition_the_batch(steps, envs, minibatches):
    # sample id = t * envs + env; each epoch's minibatches use every sample exactly once
    ids = np.arange(steps * envs).reshape(steps, envs)
    keys = jax.random.split(jax.random.key(3), envs)
    order = jax.vmap(lambda k: jax.random.permutation(k, steps))(keys).T
    mbs = np.asarray(stratified_minibatches(jnp.asarray(ids), order, minibatches))
    assert mbs.shape == (minibatches, steps * envs // minibatches)
    assert sorted(mbs.ravel().tolist()) == list(range(steps * envs))
    env_of = mbs % envs
    groups = math.lcm(minibatches, steps) // steps
    for mb in env_of:  # every minibatch: one env group, each env equally often
        counts = np.bincount(mb, minlength=envs)
        assert len({e % groups for e in mb}) == 1
        assert set(counts[counts > 0]) == {steps * envs // minibatches // (envs // groups)}
    assert (mbs[0] // envs >= steps // math.gcd(minibatches, steps)).any()  # shuffled in time
    # a device's shard of envs cuts its part of the same global minibatches
    half = envs // 2
    if half % groups == 0 and (steps * half) % minibatches == 0:
        local = stratified_minibatches(jnp.asarray(ids[:, half:]), order[:, half:], minibatches)
        for g, l in zip(mbs, np.asarray(local), strict=True):
            assert set(l.tolist()) <= set(g.tolist())


def test_gaussian_log_prob_and_entropy():
    mean, log_std = jnp.array([0.5, -1.0]), jnp.array([0.0, math.log(2.0)])
    action = jnp.array([1.5, 0.0])
    # N(1.5; 0.5, 1) * N(0; -1, 2): z = (1, 0.5)
    expected = -0.5 * (1.0 + 0.25) - math.log(2.0) - math.log(2 * math.pi)
    np.testing.assert_allclose(gaussian_log_prob(mean, log_std, action), expected, rtol=1e-6)
    expected_entropy = 2 * 0.5 * math.log(2 * math.pi * math.e) + math.log(2.0)
    np.testing.assert_allclose(gaussian_entropy(log_std), expected_entropy, rtol=1e-6)


def test_relative_actions_log_std_floor_and_hidden_obs():
    """relative_actions adds the raw observation's first action_size entries (the joint
    positions) to the actor's output; log_std_floor clamps the log-std from below;
    hidden_obs entries do not change the output."""
    obs = jnp.arange(24.0).reshape(2, 12) / 10.0
    stats = RunningStats.create(12).replace(mean=jnp.full(12, 0.3), var=jnp.full(12, 4.0))
    outputs = {}
    for relative in (False, True):
        config = TrainConfig.of(relative_actions=relative, log_std_floor=-3.0)
        network = make_network(config, 6)
        params = network.init(jax.random.key(0), obs[0], obs[0])  # same params both times
        params["params"]["log_std"] = jnp.array([-5.0, -3.0, -3.0, -5.0, -4.0, -10.0])
        outputs[relative] = forward(network, params, stats, obs, config.ppo.obs_clip)
    (mean_abs, log_std, value_abs), (mean_rel, _, value_rel) = outputs[False], outputs[True]
    assert float(jnp.abs(mean_abs).max()) > 1e-4  # the actor's output is not zero
    np.testing.assert_allclose(mean_rel, mean_abs + obs[:, :6], rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(value_rel, value_abs)
    np.testing.assert_array_equal(log_std, jnp.full((2, 6), -3.0))
    hidden = TrainConfig.of(hidden_obs=(3, 11))
    network = make_network(hidden, 6)
    params = network.init(jax.random.key(0), obs[0], obs[0])
    changed = obs.at[:, 3].add(5.0).at[:, 11].add(-7.0)
    np.testing.assert_array_equal(
        forward(network, params, stats, changed, 10.0)[0],
        forward(network, params, stats, obs, 10.0)[0],
    )
    assert not np.allclose(  # an entry that is seen does change the output
        forward(network, params, stats, obs.at[:, 4].add(5.0), 10.0)[0],
        forward(network, params, stats, obs, 10.0)[0],
    )
    with pytest.raises(ValueError, match="log_std_floor"):
        PPOConfig(init_log_std=-2.0, log_std_floor=-1.0)


def test_running_stats_match_numpy():
    rng = np.random.default_rng(1)
    batches = [rng.normal(3.0, 5.0, size=(n, 4)).astype(np.float32) for n in (7, 100, 33)]
    stats = RunningStats.create(4)
    for batch in batches:
        stats = update_stats(stats, jnp.asarray(batch))
    everything = np.concatenate(batches)
    np.testing.assert_allclose(stats.mean, everything.mean(0), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(stats.var, everything.var(0), rtol=1e-3)
    np.testing.assert_allclose(stats.count, len(everything), rtol=1e-5)


# --------------------------------------------------------------------------- config


def test_lr_schedules():
    linear = make_lr_schedule(PPOConfig(num_steps=8, total_timesteps=80, num_minibatches=2))
    np.testing.assert_allclose([linear(0), linear(5), linear(9)], [3e-4, 1.5e-4, 3e-5], rtol=1e-5)
    ros = PRESETS["ros2learn"].ppo
    exp = make_lr_schedule(ros)
    np.testing.assert_allclose(exp(100), 3e-3 * math.exp(-0.1918), rtol=1e-5)
    np.testing.assert_allclose(exp(10_000), 1e-4, rtol=1e-6)  # floored


def test_presets_hold_the_papers_hyperparameters():
    paper = PRESETS["paper"].ppo
    assert (paper.num_envs, paper.num_steps, paper.num_minibatches) == (1, 2048, 32)
    assert (paper.update_epochs, paper.gamma, paper.gae_lambda, paper.clip_eps) == (
        10,
        0.99,
        0.95,
        0.2,
    )
    assert (paper.vf_coef, paper.ent_coef, paper.learning_rate, paper.seed) == (0.5, 0, 3e-4, 0)
    assert paper.hidden_sizes == (64, 64) and paper.total_timesteps == 10**8
    assert paper.lr_schedule == "linear" and not paper.normalize_obs
    assert (paper.adam_eps, paper.max_grad_norm, paper.clip_value) == (1e-5, 0.5, True)
    ros = PRESETS["ros2learn"].ppo
    assert (ros.hidden_sizes, ros.num_steps, ros.num_minibatches) == ((16, 16), 1024, 4)
    assert (ros.clip_eps, ros.vf_coef, ros.lr_schedule) == (0.25, 1.0, "exp")
    default = PRESETS["default"]
    assert default.ppo.num_envs >= 1024 and default.ppo.normalize_obs
    # the orientation fixes of benchmarks/NOTES.md section 12 are on in the default
    assert default.policy.canonical_quat and default.curriculum.bound_coef == 1.0
    assert default.ppo.init_log_std == -1.0 and default.curriculum.train_collision_penalty == 1.0
    assert default.curriculum.train_reward == "beta=0.5,gamma=0.02"
    assert default.curriculum.train_reward_until == 0.5
    # Overridable in one call; the preset itself is never mutated.
    tuned = default.replace(num_envs=4096, learning_rate=1e-3)
    assert tuned.ppo.num_envs == 4096 and default.ppo.num_envs == 2048
    # cpu: the default with the fields of benchmarks/results/cpu/MARA/config.json changed
    cpu, base = PRESETS["cpu"].flat(), default.flat()
    changed = {k: v for k, v in cpu.items() if v != base[k]}
    assert changed == {
        "num_envs": 256,
        "num_steps": 16,
        "num_minibatches": 4,
        "learning_rate": 1e-3,
        "total_timesteps": 3_000_000,
        # the CPU recipe as measured (benchmarks/results/cpu/): no orientation fixes
        "canonical_quat": False,
        "bound_coef": 0.0,
        "train_collision_penalty": 0.0,
        "train_reward": "",
    }


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"num_envs": 3, "num_steps": 5, "num_minibatches": 4}, "does not divide the batch"),
        ({"total_timesteps": 10}, "less than one update"),
        ({"gamma": 1.5}, "gamma"),
        ({"lr_schedule": "cosine"}, "choose one of"),
        ({"hidden_sizes": ()}, "hidden_sizes"),
        ({"num_envs": 0}, "num_envs"),
        ({"num_envs": 2**20, "total_timesteps": 2**60}, "overflows"),
        ({"bogus": 1}, "unknown PPOConfig, PolicyConfig or CurriculumConfig field"),
        ({"reward_scale": 0.0}, "reward_scale"),
        ({"reward_scale": float("nan")}, "reward_scale"),
    ],
)
def test_invalid_config_raises_clear_error(overrides, message):
    with pytest.raises(ValueError, match=message):
        PRESETS["default"].replace(**overrides)


def test_config_round_trips_through_json_dict():
    for config in PRESETS.values():
        assert TrainConfig.from_dict(config.to_dict()) == config
        assert TrainConfig.from_dict(config.flat()) == config  # a pre-split flat dict
    assert RunConfig.from_dict(RunConfig().to_dict()) == RunConfig()


def test_flags_cover_every_field_and_resolve_ambiguity():
    parser = argparse.ArgumentParser(allow_abbrev=False)
    sections = (
        Section("ppo", PPOConfig),
        Section("eval", EvalConfig),
        Section("env", EnvConfig, exclude=("reward", "randomization")),
        Section("env", RewardParams),
        Section("randomization", RandomizeConfig),
    )
    add_flags(parser, sections)
    strings = {s for a in parser._actions for s in a.option_strings}
    for section in sections:
        for name in section.field_names():
            assert f"--{section.name}.{name}" in strings
    # gamma and seed: the short flag belongs to the first section that has the field.
    args = parser.parse_args(
        "--gamma 0.9 --env.gamma 2 --seed 3 --eval.seed 4 --hidden_sizes 8 8 "
        "--normalize_obs false --driver real --target_pos 0 0.1 0.7".split()
    )
    assert overrides(args, "ppo") == {
        "gamma": 0.9,
        "seed": 3,
        "hidden_sizes": (8, 8),
        "normalize_obs": False,
    }
    assert overrides(args, "eval") == {"seed": 4}
    assert overrides(args, "env") == {"gamma": 2.0, "driver": "real", "target_pos": (0, 0.1, 0.7)}
    helps = {a.dest: a.help for a in parser._actions}
    assert "GAE lambda" in helps["ppo.gae_lambda"]
    assert "rad/s" in helps["env.velocity"]
    with pytest.raises(SystemExit):
        parser.parse_args(["--driver", "fast"])


# --------------------------------------------------------------------- learning


def test_toy_env_follows_the_env_contract():
    """The toy env is a plain class: it works with BatchedEnv and PPO because it has the
    members of `mara_mjx.Env`, not because it inherits anything."""
    env = PointReach()
    assert isinstance(env, mara_mjx.Env)
    assert isinstance(env.reset(jax.random.key(0)), mara_mjx.EnvStateLike)


def test_ppo_learns_the_toy_task(toy_history):
    _, history = toy_history
    assert history["valid"].all() and len(history["valid"]) == TOY_CONFIG.ppo.num_updates
    first, last = history["reward_mean"][:3].mean(), history["reward_mean"][-3:].mean()
    # An untrained policy (mean ~0, std 1) scores about -5 * 1.1; a trained one near 0.
    assert first < -3.0
    assert last > first + 2.5, (first, last)
    assert history["det_error_mm"][-3:].mean() < 0.35 * history["det_error_mm"][:3].mean()
    assert history["entropy"][-1] < history["entropy"][0]
    finished = history["episode_return"][np.isfinite(history["episode_return"])]
    assert len(finished) > 10 and finished[-3:].mean() > finished[:3].mean()
    assert np.all(np.isfinite(history["loss"])) and np.all(history["learning_rate"] > 0)


def test_run_is_chunk_invariant_and_compiles_once(toy):
    """n updates in one call == the same updates over several calls (exact resume), and
    the masked scan never retraces."""
    trainer, state = toy
    one_call, m1 = trainer.run(state, 3)
    two_calls, m2a = trainer.run(state, 1)
    two_calls, m2b = trainer.run(two_calls, 2)
    chex.assert_trees_all_equal(jax.tree.map(_plain, one_call), jax.tree.map(_plain, two_calls))
    np.testing.assert_array_equal(m1["valid"], [True, True, True, False])
    np.testing.assert_array_equal(m1["loss"][:3], np.r_[m2a["loss"][:1], m2b["loss"][:2]])
    assert int(one_call.update) == 3
    assert trainer.run._cache_size() == 1


def test_checkpoint_round_trip_resumes_exactly(toy, tmp_path):
    trainer, state = toy
    state, _ = trainer.run(state, 2)
    meta = {
        "env_name": "PointReach",
        "env_config": {},
        "observation_size": 6,
        "action_size": 3,
        **TOY_CONFIG.to_dict(),
        "run": {},
        "eval": {},
        "progress": {"update": 2},
    }
    path = ckpt.save_checkpoint(tmp_path / "checkpoints" / ckpt.checkpoint_name(2), state, meta)
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temp left
    assert ckpt.find_checkpoint(tmp_path) == path
    arrays, loaded_meta = ckpt.load_checkpoint(path)
    assert loaded_meta["progress"] == {"update": 2}
    template = jax.eval_shape(trainer.init, jax.random.key(0))
    restored = ckpt.arrays_to_state(arrays, template)
    chex.assert_trees_all_equal(jax.tree.map(_plain, state), jax.tree.map(_plain, restored))
    after, _ = trainer.run(state, 1)
    after_restored, _ = trainer.run(restored, 1)
    chex.assert_trees_all_equal(jax.tree.map(_plain, after), jax.tree.map(_plain, after_restored))
    assert trainer.run._cache_size() == 1  # restored arrays have the same types

    # The policy artefact: params + config + normaliser, through the one factory.
    from_state = make_policy(state, TOY_CONFIG)
    from_file = make_policy(path)
    obs = jax.random.normal(jax.random.key(1), (5, 6)) * 3
    np.testing.assert_array_equal(from_state(obs), from_file(obs))
    assert from_file(obs[0]).shape == (3,)
    assert from_file.obs_stats is not None
    # jitted vs eager: XLA may fuse differently, so equal up to float32 rounding
    jitted = jax.jit(lambda p, o: p(o))(from_file, obs)
    np.testing.assert_allclose(jitted, from_file(obs), rtol=1e-5, atol=1e-7)


def test_make_policy_rejects_missing_normaliser(toy):
    _, state = toy
    with pytest.raises(ValueError, match="normalize_obs"):
        make_policy(state.params, TOY_CONFIG)
    plain = make_policy(state.params, TOY_CONFIG.replace(normalize_obs=False))
    assert plain(jnp.zeros(6)).shape == (3,)


def test_deterministic_policy_solves_the_toy_task(toy_history):
    state, _ = toy_history
    policy = make_policy(state, TOY_CONFIG)
    env = PointReach()
    starts = jax.vmap(env.reset)(jax.random.split(jax.random.key(7), 32))
    after = jax.vmap(env.step)(starts, policy(starts.obs))
    before = float(jnp.mean(starts.metrics["distance"]))
    assert float(jnp.mean(after.metrics["distance"])) < 0.3 * before


def test_checkpoint_errors_are_clear(tmp_path):
    with pytest.raises(ckpt.CheckpointError, match="does not exist"):
        ckpt.load_checkpoint(tmp_path / "nothing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"definitely not a zip file")
    with pytest.raises(ckpt.CheckpointError, match="corrupt"):
        ckpt.load_checkpoint(bad)
    with pytest.raises(ckpt.CheckpointError, match="no checkpoints"):
        ckpt.find_checkpoint(tmp_path)


def _plain(x):
    """Key arrays as their data, for tree comparisons."""
    if jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
        return jax.random.key_data(x)
    return x


def test_task_space_actions_are_one_damped_least_squares_step():
    """task_space_actions: mean = q + J^T (J J^T + lambda^2 I)^-1 (scaled actor output), J the
    TCP Jacobian at the observed q, checked against C MuJoCo's mj_jacSite; the log-std and
    value are those of the joint-space network; invalid combinations are refused."""
    import mujoco

    from mara_mjx.envs import task_space
    from mara_mjx.envs.arm import load_model

    obs = jnp.array(
        [[0.3, -0.4, 0.8, 0.1, 0.9, -0.2, 0.05, -0.1, 0.2, 0.0, 0.0, 0.0],
         [-1.2, 0.6, -0.3, 2.0, 1.1, 0.4, -0.3, 0.02, 0.1, 0.0, 0.0, 0.0]]
    )  # fmt: skip
    out = {}
    for task in (False, True):
        config = TrainConfig.of(relative_actions=True, task_space_actions=task)
        network = make_network(config, 6)
        params = network.init(jax.random.key(3), obs[0], obs[0])
        out[task] = forward(network, params, None, obs, config.ppo.obs_clip)
    u = out[False][0] - obs[:, :6]  # the actor's raw output (same params both times)
    assert float(jnp.abs(u).max()) > 1e-4
    model = load_model()
    data = mujoco.MjData(model)
    scale = np.array([task_space.POSITION_SCALE] * 3 + [task_space.ROTATION_SCALE] * 3)
    for i in range(len(obs)):
        data.qpos[:] = np.asarray(obs[i, :6])
        mujoco.mj_forward(model, data)
        jacp, jacr = np.zeros((3, 6)), np.zeros((3, 6))
        mujoco.mj_jacSite(model, data, jacp, jacr, model.site("tcp").id)
        jac = np.vstack([jacp, jacr])
        gram = jac @ jac.T + task_space.DAMPING**2 * np.eye(6)
        dq = jac.T @ np.linalg.solve(gram, np.asarray(u[i], np.float64) * scale)
        np.testing.assert_allclose(out[True][0][i], np.asarray(obs[i, :6]) + dq, atol=2e-5)
    np.testing.assert_array_equal(out[True][1], out[False][1])
    np.testing.assert_array_equal(out[True][2], out[False][2])
    with pytest.raises(ValueError, match="relative_actions"):
        TrainConfig.of(task_space_actions=True)
    with pytest.raises(ValueError, match="6 joints"):
        net = make_network(TrainConfig.of(relative_actions=True, task_space_actions=True), 4)
        net.init(jax.random.key(0), obs[0], obs[0])


def test_max_joint_step_squashes_the_mean_and_is_validated():
    """max_joint_step m: mean = q + m tanh(out / m), so every joint target is within m of
    the observed joints and small outputs pass nearly unchanged; invalid values refused."""
    obs = jnp.array([[0.3, -0.4, 0.8, 0.1, 0.9, -0.2, 0.05, -0.1, 0.2, 0.0, 0.0, 0.0]])
    config = TrainConfig.of(relative_actions=True)
    network = make_network(config, 6)
    params = network.init(jax.random.key(0), obs[0], obs[0])
    params = jax.tree.map(lambda x: 3.0 * x + 0.2, params)  # outputs well beyond m
    free = forward(network, params, None, obs, config.ppo.obs_clip)[0] - obs[:, :6]
    m = 0.015
    limited = make_network(config.replace(max_joint_step=m), 6)
    got = forward(limited, params, None, obs, config.ppo.obs_clip)[0] - obs[:, :6]
    assert float(jnp.abs(free).max()) > 10 * m  # the squash has something to do
    np.testing.assert_allclose(got, m * jnp.tanh(free / m), rtol=1e-5, atol=1e-7)
    assert float(jnp.abs(got).max()) <= m * (1 + 1e-6)
    with pytest.raises(ValueError, match="relative_actions"):
        TrainConfig.of(max_joint_step=0.01)
    with pytest.raises(ValueError, match="max_joint_step"):
        TrainConfig.of(relative_actions=True, max_joint_step=-0.1)


def test_orientation_bonus_peaks_at_the_exact_pose_and_skips_collisions():
    """orientation_bonus: w exp(-d / d0) exp(-theta / theta0), 0 on colliding steps; its
    slope in theta at the goal is w / theta0; cleared for a task without orientation."""
    import mara_mjx
    from mara_mjx.ppo.config import for_env
    from mara_mjx.ppo.curriculum import orientation_bonus

    config = TrainConfig.of(orientation_bonus=5.0, orientation_bonus_angle=0.1)
    metrics = {
        "distance": jnp.array([0.0, 0.0, 0.001, 0.0, 0.0]),
        "angle": jnp.array([0.0, 0.01, 0.0, 0.2, 0.0]),
        "collided": jnp.array([False, False, False, False, True]),
    }
    got = np.asarray(orientation_bonus(metrics, config.curriculum))
    d, theta = np.array([0, 0, 0.001, 0, 0]), np.array([0, 0.01, 0, 0.2, 0])
    expected = 5.0 * np.exp(-d / 0.005 - theta / 0.1)
    expected[4] = 0.0
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    assert got[0] == got.max() and got[4] == 0.0
    # one degree near the goal is worth ~ w / theta0 * pi / 180 = 0.87 (the env's: ~0.01)
    slope = (got[0] - got[1]) / 0.01
    assert 45.0 < slope < 50.0
    assert for_env(config, mara_mjx.make("MARA")).curriculum.orientation_bonus == 0.0
    assert for_env(config, mara_mjx.make("MARAOrient")).curriculum.orientation_bonus == 5.0
    with pytest.raises(ValueError, match="orientation_bonus_angle"):
        TrainConfig.of(orientation_bonus_angle=0.0)


def test_ik_prior_step_is_a_newton_step_toward_the_observed_pose():
    """pose_step repeated from near a pose converges to it (position and orientation, and
    position alone); rotation_vector is axis * angle for q and -q; the step is bounded."""
    from mara_mjx.envs.geometry import quat_conj, quat_mul
    from mara_mjx.envs.mara import _shared_arm
    from mara_mjx.envs.task_space import MAX_STEP_JOINT, pose_step, rotation_vector

    axis, angle = np.array([0.6, -0.8, 0.0]), 0.7
    quat = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])
    for sign in (1.0, -1.0):
        np.testing.assert_allclose(
            rotation_vector(jnp.asarray(sign * quat)), angle * axis, atol=1e-6
        )
    np.testing.assert_allclose(rotation_vector(jnp.array([1.0, 0, 0, 0])), 0.0, atol=0)

    arm = _shared_arm(False)
    rng = np.random.default_rng(0)
    target_q = jnp.asarray(rng.uniform(-1.2, 1.2, (16, 6)), jnp.float32)
    q0 = target_q + jnp.asarray(rng.normal(0, 0.1, (16, 6)), jnp.float32)
    pose = jax.vmap(lambda q: arm.pose_with(q, "lean", collide=False))
    target = pose(target_q)

    @functools.partial(jax.jit, static_argnums=1)
    def run(q, orientation):
        def one(q, _):
            p = pose(q)
            e = p.tcp_pos - target.tcp_pos
            err = quat_mul(p.tcp_quat, quat_conj(target.tcp_quat))
            dq = pose_step(q, e, err if orientation else None)
            return q + dq, (
                jnp.linalg.norm(e, axis=-1),
                2 * jnp.arccos(jnp.minimum(1, jnp.abs(err[:, 0]))),
                dq,
            )

        return jax.lax.scan(one, q, None, length=8)[1]

    for orientation in (True, False):
        dist, angle_err, dq = jax.tree.map(np.asarray, run(q0, orientation))
        assert np.median(dist[0]) > 0.02 and np.median(dist[-1]) < 1e-5, orientation
        assert np.mean(dist[-1] < 1e-3) >= 0.8
        if orientation:
            assert np.median(angle_err[0]) > 0.05 and np.median(angle_err[-1]) < 2e-3
        assert np.abs(dq).max() <= MAX_STEP_JOINT * (1 + 1e-5)


def test_ik_prior_residual_adds_the_ik_step_and_is_validated():
    """ik_prior: both networks get the IK step's features; 'residual' adds the step to the
    mean's displacement (the actor's own output is the same); bad values are refused, and
    an env without a MARA observation is refused by for_env."""
    import mara_mjx
    from mara_mjx.ppo.config import for_env
    from mara_mjx.ppo.networks import ik_prior_step

    env = mara_mjx.make("MARACollisionOrient")
    obs = env.reset(jax.random.key(0)).obs
    obs = jnp.stack([obs, obs.at[:6].set(jnp.array([0.3, -0.4, 0.8, 0.1, 0.9, -0.2]))])
    out = {}
    for prior in ("features", "residual"):
        config = for_env(TrainConfig.of(relative_actions=True, ik_prior=prior), env)
        assert config.policy.quat_index == 9
        network = make_network(config, 6)
        params = network.init(jax.random.key(3), obs[0], obs[0])
        out[prior] = forward(network, params, None, obs, config.ppo.obs_clip)
    step = ik_prior_step(obs, 9)[0]
    assert float(jnp.abs(step).max()) > 0.01
    np.testing.assert_allclose(out["residual"][0], out["features"][0] + step, atol=1e-6)
    np.testing.assert_array_equal(out["residual"][2], out["features"][2])
    with pytest.raises(ValueError, match=r"ik_prior='ik' is not valid; choose one of"):
        TrainConfig.of(relative_actions=True, ik_prior="ik")
    with pytest.raises(ValueError, match="relative_actions"):
        TrainConfig.of(ik_prior="residual")

    class Other:
        observation_layout = [{"name": "x", "start": 0, "stop": 4}]
        action_size = 2

    with pytest.raises(ValueError, match="MARA arm's observation"):
        for_env(TrainConfig.of(ik_prior="features"), Other())


def _residual_mean(config: PPOConfig, batch: jax.Array) -> jax.Array:
    """The policy mean of a fresh ik_prior network whose actor head is biased 0.05 away
    from 0 (a visible learnt correction), on a batch of raw observations."""
    network = make_network(config, 6)
    params = network.init(jax.random.key(3), batch[0], batch[0])
    head = params["params"]["actor"]
    last = sorted(k for k in head if k.startswith("Dense"))[-1]
    head[last]["bias"] = head[last]["bias"] + 0.05
    return forward(network, params, None, batch, config.ppo.obs_clip)[0]


def test_ik_gate_fades_the_learnt_correction_to_zero_at_the_target():
    """ik_gate s: mean = q + ik_step + tanh(|e| / s) x the actor's correction; at the
    target position (e = 0) the mean is q + ik_step exactly, far from it the ungated
    residual; bad values are refused."""
    import mara_mjx
    from mara_mjx.ppo.config import for_env
    from mara_mjx.ppo.networks import ik_gate, ik_prior_step

    env = mara_mjx.make("MARACollisionOrient")
    obs = env.reset(jax.random.key(0)).obs
    at_goal = obs.at[6:9].set(0.0)
    near = obs.at[6:9].set(jnp.array([0.003, 0.0, -0.004]))
    batch = jnp.stack([obs, at_goal, near])
    outs = {}
    for gate in (0.0, 0.01):
        config = for_env(
            TrainConfig.of(relative_actions=True, ik_prior="residual", ik_gate=gate), env
        )
        outs[gate] = _residual_mean(config, batch)
    q, step = batch[:, :6], ik_prior_step(batch, 9)[0]
    g = ik_gate(batch, 0.01)
    np.testing.assert_allclose(g[1], 0.0, atol=1e-5)
    np.testing.assert_allclose(g[2], np.tanh(0.5), rtol=1e-4)
    assert float(g[0]) > 0.99  # the reset pose is far from the target
    correction = outs[0.0] - q - step
    assert float(jnp.abs(correction).min()) > 0.01
    np.testing.assert_allclose(outs[0.01], q + step + g[:, None] * correction, atol=1e-5)
    np.testing.assert_allclose(outs[0.01][1], q[1] + step[1], atol=1e-5)
    with pytest.raises(ValueError, match="ik_gate=0.01 gates the correction"):
        TrainConfig.of(relative_actions=True, ik_prior="features", ik_gate=0.01)
    with pytest.raises(ValueError, match="ik_gate"):
        TrainConfig.of(relative_actions=True, ik_prior="residual", ik_gate=-1.0)
    with pytest.raises(ValueError, match="ik_wrap=true changes the IK step"):
        TrainConfig.of(ik_wrap=True)
    with pytest.raises(ValueError, match="ik_gate_wrap=true closes the gate"):
        TrainConfig.of(relative_actions=True, ik_prior="residual", ik_wrap=True, ik_gate_wrap=True)


def test_pose_step_wrap_takes_the_last_joint_the_long_way_past_its_limit():
    """pose_step(wrap_last=True): near the target, where the last joint's Newton target
    lies past its limit, the step on it goes the other way (the same angle 2 pi away);
    elsewhere (no limit in the way, or far from the target) it is the plain step.
    Repeated, the wrapped step reaches the pose the plain one stops short of."""
    from mara_mjx.envs.geometry import quat_conj, quat_mul
    from mara_mjx.envs.task_space import (
        last_joint_range,
        nominal_chain,
        pose_step,
        pose_step_wrapping,
        rotation_vector,
    )

    chain = nominal_chain()
    lo6, hi6 = last_joint_range()
    assert hi6 - lo6 > 2 * np.pi - 0.01
    goal = jnp.array([0.4, -0.5, 0.9, 0.1, 1.2, hi6 - 0.1])
    tpos, tquat = chain.tcp(goal)

    def error(q):
        pos, quat = chain.tcp(q)
        return pos - tpos, quat_mul(quat, quat_conj(tquat))

    @functools.partial(jax.jit, static_argnums=1)
    def run(q, wrap, n=80):  # n closed-loop steps, one compiled loop
        def body(_, q):
            e, r = error(q)
            return jnp.clip(q + pose_step(q, e, r, wrap), lo6, hi6)

        return jax.lax.fori_loop(0, n, body, q)

    # no limit in the way: the same step with and without wrap
    near = goal.at[5].add(-0.3)
    e, r = error(near)
    np.testing.assert_allclose(pose_step(near, e, r, True), pose_step(near, e, r, False))
    # joint 6 at -hi6 + 0.2: the target's angle hi6 - 0.1 is 0.3 rad away downward (across
    # +-pi), past the lower limit; the wrapped step goes up, the long way round
    blocked = goal.at[5].set(lo6 + 0.2)
    e, r = error(blocked)
    plain, wrapped = pose_step(blocked, e, r, False), pose_step(blocked, e, r, True)
    assert float(plain[5]) < 0.0 < float(wrapped[5])
    q_plain, q_wrap = run(blocked, False), run(blocked, True)

    # on the way round the other joints hold the TCP's position and the tool axis
    @jax.jit
    def wrapping_step(q):  # (next q, still wrapping, |e| after the step)
        dq, wrapping = pose_step_wrapping(q, *error(q), True)
        q = jnp.clip(q + dq, lo6, hi6)
        return q, wrapping, jnp.linalg.norm(error(q)[0])

    q, worst = blocked.at[:5].add(0.002), 0.0
    for _ in range(30):
        after, wrapping, e_after = wrapping_step(q)
        if not bool(wrapping):
            break
        q, worst = after, max(worst, float(e_after))
    assert 0.5 < float(q[5] - blocked[5]) and worst < 2e-3
    assert float(jnp.linalg.norm(rotation_vector(error(q_plain)[1]))) > 0.05
    assert float(jnp.linalg.norm(rotation_vector(error(q_wrap)[1]))) < 1e-3
    np.testing.assert_allclose(q_wrap, goal, atol=1e-3)
    # far from the target position the step is the plain one
    far = blocked.at[1].add(0.3)
    e, r = error(far)
    assert float(jnp.linalg.norm(e)) > 0.02
    np.testing.assert_allclose(pose_step(far, e, r, True), pose_step(far, e, r, False))
    # pose_step_wrapping flags the long way round, and only it
    flags = [
        bool(pose_step_wrapping(x, *error(x), wrap)[1])
        for x, wrap in ((near, True), (blocked, True), (blocked, False), (far, True))
    ]
    assert flags == [False, True, False, False]


def test_ik_gate_wrap_leaves_the_ik_step_alone_while_it_takes_the_long_way():
    """ik_gate_wrap: where the IK step turns the last joint the long way round, the mean
    is q + the IK step exactly (the gate closed), elsewhere the gated residual."""
    import mara_mjx
    from mara_mjx.envs.geometry import quat_conj, quat_mul
    from mara_mjx.envs.task_space import last_joint_range, nominal_chain
    from mara_mjx.ppo.config import for_env
    from mara_mjx.ppo.networks import ik_gate, ik_prior_step

    env = mara_mjx.make("MARACollisionOrient")
    chain, (lo6, hi6) = nominal_chain(), last_joint_range()
    goal = jnp.array([0.4, -0.5, 0.9, 0.1, 1.2, hi6 - 0.1])
    tpos, tquat = chain.tcp(goal)
    rows = []
    for q in (goal.at[5].set(lo6 + 0.2), goal.at[5].add(-0.3)):  # blocked, free
        pos, quat = chain.tcp(q)
        obs = env.reset(jax.random.key(0)).obs.at[:6].set(q)
        obs = obs.at[6:9].set(pos - tpos + jnp.array([0.004, 0.0, 0.0]))
        rows.append(obs.at[9:13].set(quat_mul(quat, quat_conj(tquat))))
    batch = jnp.stack(rows)
    step, wrapping = ik_prior_step(batch, 9, True)
    assert wrapping.tolist() == [True, False]
    outs = {}
    for gate_wrap in (False, True):
        config = for_env(
            TrainConfig.of(
                relative_actions=True,
                ik_prior="residual",
                ik_gate=0.01,
                ik_wrap=True,
                ik_gate_wrap=gate_wrap,
            ),
            env,
        )
        outs[gate_wrap] = _residual_mean(config, batch)
    q, g = batch[:, :6], ik_gate(batch, 0.01)
    assert float(g[0]) > 0.3
    assert float(jnp.abs(outs[False][0] - q[0] - step[0]).min()) > 0.005  # gated residual
    np.testing.assert_allclose(outs[True][0], q[0] + step[0], atol=1e-6)  # the IK step alone
    np.testing.assert_allclose(outs[True][1], outs[False][1], atol=1e-6)  # not wrapping


def test_train_limit_penalty_is_zero_inside_the_soft_range_and_one_at_a_limit():
    """limit_penalty: per joint 0 within f of the half-range, 1 at the limit, linear
    between, summed over joints; the fields are validated."""
    from mara_mjx.ppo.curriculum import limit_penalty

    lower, upper = jnp.array([-1.0, -3.0]), jnp.array([1.0, 1.0])  # centres 0, -1; halves 1, 2
    q = jnp.array([[0.0, -1.0], [0.9, -1.0], [0.95, -1.0], [1.0, -1.0], [-1.0, 1.0], [1.0, -3.0]])
    got = np.asarray(limit_penalty(q, lower, upper, 0.9))
    np.testing.assert_allclose(got, [0.0, 0.0, 0.5, 1.0, 2.0, 2.0], atol=1e-5)
    with pytest.raises(ValueError, match="train_limit_penalty"):
        TrainConfig.of(train_limit_penalty=-1.0)
    with pytest.raises(ValueError, match="train_limit_soft"):
        TrainConfig.of(train_limit_soft=1.0)


def test_rate_limited_keeps_the_direction_and_bounds_every_joint_step():
    """policy.rate_limited(p, m, lo, hi): the target clipped to [lo, hi], then q + d x
    min(1, m / max|d|): the largest joint step is m, the others in proportion (the same
    direction in joint space), small steps untouched, a joint pushing past its limit
    does not slow the others, a non-finite target stays in its own entry; a pytree
    through jit; bad m refused."""
    from mara_mjx.ppo.policy import rate_limited

    step = jnp.array([0.6, -0.3, 0.15, 0.0, 0.001, -0.06])
    base = jax.tree_util.Partial(lambda obs: obs[..., :6] + step)
    obs = jnp.zeros((2, 20)).at[1, :6].set(jnp.array([0.3, -0.2, 0.1, 0.5, -0.4, 0.2]))
    limited = jax.jit(lambda p, o: p(o))(rate_limited(base, 0.015), obs)
    moved = limited - obs[:, :6]
    np.testing.assert_allclose(np.abs(moved).max(-1), [0.015, 0.015], rtol=1e-6)
    np.testing.assert_allclose(moved, np.broadcast_to(step * 0.015 / 0.6, (2, 6)), atol=1e-7)
    small = rate_limited(base, 1.0)(obs)
    np.testing.assert_allclose(small - obs[:, :6], np.broadcast_to(step, (2, 6)), atol=1e-6)
    # joint 4 at its upper limit asks 0.5 further: clipped away, joint 1 keeps full speed
    lo, hi = -jnp.full(6, 3.14), jnp.full(6, 3.14)
    q = jnp.zeros(20).at[3].set(3.14)
    pushing = jax.tree_util.Partial(lambda o: o[..., :6] + jnp.array([0.2, 0, 0, 0.5, 0, 0]))
    out = rate_limited(pushing, 0.015, lo, hi)(q) - q[:6]
    np.testing.assert_allclose(out, [0.015, 0, 0, 0, 0, 0], atol=1e-7)
    nan = jax.tree_util.Partial(lambda o: o[..., :6] + jnp.array([0.3, jnp.nan, 0, 0, 0, 0]))
    out = rate_limited(nan, 0.015)(jnp.zeros(20))
    assert np.isnan(out[1]) and float(out[0]) == pytest.approx(0.015)
    with pytest.raises(ValueError, match="max_step=0.0 must be > 0"):
        rate_limited(base, 0.0)


def test_evaluation_rate_limit_uses_the_servo_travel_and_needs_the_real_driver(monkeypatch):
    """EvalConfig.rate_limit: the evaluation limits the policy's targets (limit_step, as
    rate_limited does) to the servos' travel per step (velocity x substeps x timestep,
    per episode) and the joint limits; on the train driver it is refused with the
    reason. Traced, not compiled."""
    import mara_mjx
    from mara_mjx.ppo import evaluation
    from mara_mjx.ppo.config import EvalConfig

    with pytest.raises(ValueError, match="rate_limit=true .* driver is 'train'"):
        evaluation.make_evaluate(mara_mjx.make("MARA"), EvalConfig(rate_limit=True))
    seen = {}
    real = evaluation.limit_step

    def spy(action, q, max_step, bounds):
        seen.update(max_step=max_step, lower=bounds[0])
        return real(action, q, max_step, bounds)

    monkeypatch.setattr(evaluation, "limit_step", spy)
    env = mara_mjx.make("MARA", driver="real", velocity=0.3)
    fn = evaluation.make_evaluate(env, EvalConfig(episodes=2, rate_limit=True))
    base = jax.tree_util.Partial(lambda obs: obs[..., :6] + 0.1)
    jax.eval_shape(fn, base)
    np.testing.assert_allclose(np.asarray(seen["max_step"]), [[0.015], [0.015]], rtol=1e-5)
    np.testing.assert_allclose(seen["lower"], env.joint_lower)


def test_probe_reach_steps_measures_the_saved_policy_from_the_reset_and_changes_nothing(toy):
    """PPOConfig.probe_reach_steps: a call of `run` ends with the deterministic policy's
    rollout from the reset; `reach_error_mm` is its mean per-axis |e| at the last step, on
    the call's last valid row (NaN elsewhere); the training itself is bitwise the same.
    Apart from `run` (probe_apart), the same numbers."""
    from mara_mjx.ppo.metrics import PROBE_REACH_EPISODES
    from mara_mjx.ppo.networks import forward

    trainer, state = toy
    probing = make_train(PointReach(), TOY_CONFIG.replace(probe_reach_steps=3), updates_per_call=4)
    plain_state, plain = trainer.run(state, 3)
    probe_state, probed = probing.run(probing.init(jax.random.key(0)), 3)
    pairs = (plain_state.params, probe_state.params)
    leaves = zip(*map(jax.tree.leaves, pairs), strict=True)
    for a, b in leaves:
        np.testing.assert_array_equal(a, b)
    reach = np.asarray(probed["reach_error_mm"])
    assert "reach_error_mm" not in plain
    assert np.isnan(reach[[0, 1, 3]]).all() and np.isfinite(reach[2]), reach
    env = PointReach()  # the probe by hand: 3 deterministic steps from the same resets
    keys = jax.random.split(jax.random.key(0), PROBE_REACH_EPISODES)
    s = jax.vmap(env.reset)(keys)
    for _ in range(3):
        mean = forward(probing.network, probe_state.params, probe_state.obs_stats, s.obs, 10.0)[0]
        s = jax.vmap(env.step)(s, mean)
    expected = 1000.0 * float(jnp.mean(s.metrics["position_error"]))
    np.testing.assert_allclose(reach[2], expected, rtol=1e-5)
    assert expected > 1.0  # an untrained policy: the number is not a constant
    # probe_apart (the train CLI's single runs): run leaves the probe out, Trainer.probe
    # gives the same column, bitwise, from its own program; a population keeps it in run
    config = TOY_CONFIG.replace(probe_reach_steps=3)
    apart = make_train(PointReach(), config, updates_per_call=4, probe_apart=True)
    apart_state, apart_metrics = apart.run(apart.init(jax.random.key(0)), 3)
    assert "reach_error_mm" not in apart_metrics and probing.probe is None
    np.testing.assert_array_equal(np.asarray(apart.probe(apart_state, 3)), reach)
    same = zip(*map(jax.tree.leaves, (apart_state.params, probe_state.params)), strict=True)
    for a, b in same:
        np.testing.assert_array_equal(a, b)
    members = make_train(PointReach(), config.replace(population=2), 4, probe_apart=True)
    assert members.probe is None


def test_with_the_reach_probe_run_leaves_out_the_saved_policys_forward_pass(monkeypatch):
    """The rollout's one-step det_* measure takes the training network's mean where the
    reach probe measures the saved policy: `run` then traces no forward pass of the saved
    network with its deployed rules (the collision guard, the orient-first zone), which
    made 37% of its compiled program (benchmarks/NOTES.md section 70); without the probe
    it does (the det_* columns are then the saved policy's accuracy)."""
    import mara_mjx.ppo.train as train_module
    from mara_mjx.ppo.presets import PRESETS

    traced = []
    real = train_module.forward
    spy = lambda network, *args: traced.append(network) or real(network, *args)  # noqa: E731
    monkeypatch.setattr(train_module, "forward", spy)
    env = mara_mjx.make("MARACollisionOrient")
    tiny = dict(num_envs=4, num_steps=4, total_timesteps=64, num_minibatches=2, update_epochs=1)
    for steps in (8, 0):
        config = PRESETS["orient_first"].replace(probe_reach_steps=steps, **tiny)
        trainer = make_train(env, config, updates_per_call=1, probe_apart=True)
        saved = make_network(trainer.config, env.action_size)
        assert trainer.network != saved  # deployed-only rules: two networks
        traced.clear()
        jax.eval_shape(trainer.run, jax.eval_shape(trainer.init, jax.random.key(0)), 1)
        assert trainer.network in traced  # the spy sees the forward passes
        assert (saved in traced) == (steps == 0), steps


def test_milestones_use_the_reach_probe_where_the_rows_have_it():
    """Time to accuracy: `reach_error_mm` (NaN on rows without a probe: no record) where
    the run has the probe, else `det_error_mm`."""
    from mara_mjx.ppo.logger import Milestones

    def row(update, det, reach=None):
        r = {"time_s": float(update), "env_steps": 10 * update, "update": update}
        return {**r, "det_error_mm": det, **({} if reach is None else {"reach_error_mm": reach})}

    probed = Milestones()
    probed.update([row(1, 0.5, float("nan")), row(2, 9.0, 3.0), row(3, 9.0, 0.8)])
    assert probed.records["5mm"]["update"] == 2 and probed.records["1mm"]["update"] == 3
    plain = Milestones()
    plain.update([row(1, 6.0), row(2, 0.5)])
    assert plain.records["5mm"]["update"] == 2 and plain.records["1mm"]["update"] == 2


def test_probe_reach_steps_under_seeds_is_each_seeds_own_probe():
    """probe_reach_steps in a seeds-vmapped program (make_seed_trainer): every seed's
    `reach_error_mm` is on its last valid row and equals the single run of that seed's."""
    from mara_mjx.ppo.members import make_seed_trainer

    config = TOY_CONFIG.replace(probe_reach_steps=2)
    trainer = make_train(PointReach(), config, updates_per_call=2, devices=1)
    seeds = make_seed_trainer(trainer, (0, 1), devices=1)
    _, metrics = seeds.run(seeds.init(), 1)
    reach = np.asarray(metrics["reach_error_mm"])
    assert reach.shape == (2, 2) and np.isfinite(reach[:, 0]).all() and np.isnan(reach[:, 1]).all()
    for i, s in enumerate((0, 1)):
        _, alone = trainer.run(trainer.init(jax.random.key(s)), 1)
        np.testing.assert_allclose(reach[i, 0], float(alone["reach_error_mm"][0]), rtol=1e-5)
    assert abs(reach[0, 0] - reach[1, 0]) > 1e-3  # the seeds' own policies


def test_toy_training_gives_the_presplit_bits(toy_history):
    """The 40 toy updates give the params recorded before the PPOConfig split
    (test_config_split.PRESPLIT; on other jax versions, skipped)."""
    from test_config_split import PRESPLIT, check_presplit, digest, same_versions

    if not same_versions():
        pytest.skip(f"reference bits recorded on jax {PRESPLIT['versions']}")
    state, _ = toy_history
    check_presplit("toy", digest((state.params, state.obs_stats)))
