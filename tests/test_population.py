"""Population training (PPOConfig.population, ppo.train.population): the exploit step's
ranking and copies, member 0 as the run's policy (from the state and from a checkpoint),
and the config's clear errors. The toy env of test_ppo keeps compiles small."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_ppo import TOY_CONFIG, PointReach

from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.config import TrainConfig
from mara_mjx.ppo.members import member_axis, population
from mara_mjx.ppo.policy import make_policy, policy_from_checkpoint
from mara_mjx.ppo.train import RunnerState, make_train


def _fake_member(key: jax.Array) -> RunnerState:
    w = jax.random.normal(key, (3,))
    return RunnerState(
        params={"w": w},
        opt_state={"m": w * 2.0},
        obs_stats={"mean": w * 3.0},
        env_state={"q": w * 4.0},
        key=key,
        update=jnp.zeros((), jnp.int32),
    )


def _fake_run(state: RunnerState, n):
    """One update per call; the fitness of a member is its own first parameter, so the
    ranking is known. Metrics have the (updates_per_call,) axis of Trainer.run."""
    metrics = {"train_reward_mean": state.params["w"][:1], "valid": jnp.array([True])}
    return state.replace(update=state.update + 1), metrics


def test_exploit_ranks_members_and_copies_the_best():
    config = TrainConfig.of(
        num_envs=1, num_steps=1, total_timesteps=10, num_minibatches=1, population=5,
        exploit_every=0.2, exploit_fraction=0.4,
    )  # fmt: skip
    init, update = population(_fake_member, _fake_run, config)
    state = jax.jit(init)(jax.random.key(3))
    assert state.fitness.shape == (5,) and member_axis(state) == 0
    # member 0 starts from the run's key itself: a single run's start
    np.testing.assert_array_equal(state.params["w"][0], _fake_member(jax.random.key(3)).params["w"])
    w0 = np.asarray(state.params["w"][:, 0])
    keys_before = jax.random.key_data(state.key)

    step = jax.jit(lambda s: update(s, 1))
    state, metrics = step(state)  # update 1: not an exploit (every 2 updates)
    np.testing.assert_allclose(state.fitness, w0)
    assert float(metrics["train_reward_mean"][0]) == pytest.approx(w0[0])  # member 0's metrics
    state, _ = step(state)  # update 2: exploit
    order = np.argsort(-w0, kind="stable")
    src = np.concatenate([order[:3], order[:2]])  # 5 - floor(5 * 0.4) kept, 2 copies
    np.testing.assert_array_equal(np.asarray(state.params["w"][:, 0]), w0[src])
    for name, scale in (("opt_state", 2.0), ("obs_stats", 3.0), ("env_state", 4.0)):
        leaf = jax.tree.leaves(getattr(state, name))[0]
        np.testing.assert_allclose(np.asarray(leaf[:, 0]), scale * w0[src], rtol=1e-6)
    assert float(state.params["w"][0, 0]) == w0.max()  # the best is member 0
    np.testing.assert_array_equal(state.fitness, np.zeros(5))
    # PRNG keys stay with their slots, so the copies diverge
    np.testing.assert_array_equal(jax.random.key_data(state.key), keys_before)


def test_last_update_always_exploits():
    config = TrainConfig.of(
        num_envs=1, num_steps=1, total_timesteps=3, num_minibatches=1, population=2,
        exploit_every=1.0,
    )  # fmt: skip
    init, update = population(_fake_member, _fake_run, config)
    state = init(jax.random.key(0))
    w0 = np.asarray(state.params["w"][:, 0])
    for _ in range(2):
        state, _ = update(state, 1)
    assert np.all(state.fitness != 0)  # not yet
    state, _ = update(state, 1)  # the last update (3 of 3)
    assert float(state.params["w"][0, 0]) == w0.max()


@pytest.fixture(scope="module")
def toy_population():
    config = TOY_CONFIG.replace(total_timesteps=16 * 16 * 4, population=3, exploit_every=0.5)
    trainer = make_train(PointReach(), config, updates_per_call=4)
    state = trainer.init(jax.random.key(0))
    state, metrics = trainer.run(state, 4)
    return trainer, state, jax.device_get(metrics)


def test_population_trains_and_member_0_is_the_policy(toy_population):
    trainer, state, metrics = toy_population
    assert state.params["params"]["log_std"].shape == (3, 3)
    assert np.all(np.isfinite(metrics["loss"])) and metrics["loss"].shape == (4,)
    assert np.all(metrics["population_fitness_spread"] >= 0)
    policy = make_policy(state, trainer.config)
    np.testing.assert_array_equal(
        policy.params["params"]["log_std"], state.params["params"]["log_std"][0]
    )
    obs = jnp.ones((5, 6))
    # the same policy back from a checkpoint
    meta = {**trainer.config.to_dict(), "action_size": 3, "observation_size": 6}
    loaded = policy_from_checkpoint(ckpt.state_to_arrays(state), meta)
    np.testing.assert_array_equal(loaded(obs), policy(obs))
    # and a seed-batched population (leading seed axis) takes member 0 of every seed
    batched = jax.tree.map(lambda x: jnp.stack([x, x]), state)
    assert member_axis(batched) == 1
    both = make_policy(batched, trainer.config)
    np.testing.assert_array_equal(
        both.params["params"]["log_std"][1], policy.params["params"]["log_std"]
    )


@pytest.mark.parametrize(
    "field, value",
    [("population", 0), ("population", 1.5), ("exploit_every", 0.0), ("exploit_fraction", 2.0)],
)
def test_bad_population_settings_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        TrainConfig.of(**{field: value})


def test_a_diverged_member_ranks_last_whatever_its_reward():
    """A member whose params turned NaN keeps a finite reward (the env holds the pose for
    NaN actions), so its fitness can be the best: the exploit step still replaces it."""
    config = TrainConfig.of(
        num_envs=1, num_steps=1, total_timesteps=2, num_minibatches=1, population=3,
        exploit_every=1.0, exploit_fraction=0.34,
    )  # fmt: skip

    def run(state: RunnerState, n):  # the fitness: 1, 2, 3 for members 0, 1, 2
        w = state.params["w"]
        reward = jnp.where(jnp.isnan(w[0]), 3.0, 1.0 + w[2])
        return state.replace(update=state.update + 1), {
            "train_reward_mean": reward[None], "valid": jnp.array([True])}  # fmt: skip

    init, update = population(_fake_member, run, config)
    state = init(jax.random.key(0))
    w = jnp.stack([jnp.array([0.0, 0.0, 0.0]), jnp.array([0.0, 0.0, 1.0]),
                   jnp.array([jnp.nan, 0.0, 0.0])])  # fmt: skip
    state = state.replace(params={"w": w})
    state, _ = update(state, 1)  # not yet an exploit
    assert float(state.fitness[2]) == 3.0  # the diverged member has the best fitness
    state, _ = update(state, 1)  # the last update: exploit
    assert np.all(np.isfinite(np.asarray(state.params["w"])))  # replaced, not copied
    np.testing.assert_array_equal(np.asarray(state.params["w"][0]), [0.0, 0.0, 1.0])
