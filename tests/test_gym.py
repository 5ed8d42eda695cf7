"""The gymnasium adapter: registration, check_env on every task, the vector env against
the jitted single env (autoreset included), bad host input.

Each env instance compiles its reset and step once (about 12 s on a 2-core CPU), so the
module builds one instance per task and one vector env, and reuses them.
"""

from __future__ import annotations

import warnings

import gymnasium
import jax
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode

import mara_mjx
from mara_mjx.adapters.gym import TASK_NAMES, MaraGymEnv, gym_id
from mara_mjx.adapters.gym_vector import MaraVectorEnv

NOISE = 0.05  # reset_noise: makes reset observations depend on the key
HORIZON = 2
N = 3


@pytest.fixture(scope="module")
def gym_envs() -> dict[str, MaraGymEnv]:
    """One unwrapped env per task. MARA is built directly with a 2-step horizon (it is
    also the vector env's reference); the others through gymnasium.make."""
    envs = {"MARA": MaraGymEnv("MARA", max_episode_steps=HORIZON, reset_noise=NOISE)}
    for task in TASK_NAMES[1:]:
        wrapped = gymnasium.make(gym_id(task), reset_noise=NOISE)
        assert "TimeLimit" not in str(wrapped)  # truncation is the env's own
        envs[task] = wrapped.unwrapped
    return envs


@pytest.fixture(scope="module")
def venv() -> MaraVectorEnv:
    return gymnasium.make_vec(
        gym_id("MARA"),
        num_envs=N,
        vectorization_mode="vector_entry_point",
        max_episode_steps=HORIZON,
        reset_noise=NOISE,
        autoreset_mode="same_step",
    )


@pytest.fixture(scope="module")
def venv_next() -> MaraVectorEnv:
    """The default autoreset mode, NEXT_STEP."""
    return gymnasium.make_vec(
        gym_id("MARA"),
        num_envs=N,
        vectorization_mode="vector_entry_point",
        max_episode_steps=HORIZON,
        reset_noise=NOISE,
    )


def test_ids_registered_without_time_limit():
    for task in TASK_NAMES:
        spec = gymnasium.spec(gym_id(task))
        assert spec.max_episode_steps is None
        assert spec.kwargs == {"task": task}
        assert spec.vector_entry_point == "mara_mjx.adapters.gym_vector:MaraVectorEnv"


def test_make_kwargs_map_to_env_options():
    env = gymnasium.make(gym_id("MARAOrient"), driver="real", velocity=0.3, alpha=4.0)
    cfg = env.unwrapped.env.config
    assert (cfg.driver, cfg.velocity, cfg.reward.alpha) == ("real", 0.3, 4.0)
    assert cfg.reward.beta == 1.1  # the task's own default survives
    with pytest.raises(ValueError, match="unknown env option"):
        gymnasium.make(gym_id("MARA"), not_an_option=1)
    with pytest.raises(ValueError, match="render_mode='ansi' is not supported.*'rgb_array'"):
        MaraGymEnv("MARA", render_mode="ansi")  # rendering itself: tests/test_play.py


# The adapter is the same for every task: the 12-value observation with both flags
# (orientation, collision penalty) off and the 16-value one with both on.
@pytest.mark.parametrize("task", ["MARA", "MARACollisionOrient"])
def test_check_env(gym_envs, task):
    env = gym_envs[task]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Box(-inf, inf) / unnormalised actions
        check_env(env, skip_render_check=True)
    size = 16 if "Orient" in task else 12
    assert env.observation_space.shape == (size,)
    assert env.observation_space.dtype == np.float32
    np.testing.assert_array_equal(env.action_space.low, env.env.joint_lower.astype(np.float32))
    np.testing.assert_array_equal(env.action_space.high, env.env.joint_upper.astype(np.float32))
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert obs.dtype == np.float32 and obs.shape == (size,)
    assert isinstance(reward, float) and isinstance(truncated, bool)
    assert set(info) == set(mara_mjx.envs.base.METRIC_KEYS)
    assert all(isinstance(v, np.ndarray) for v in info.values())
    assert info["position_error"].shape == (3,)
    # Compiled once per instance, whatever check_env threw at it.
    assert env._jit_reset._cache_size() == 1 and env._jit_step._cache_size() == 1


def test_horizon_seed_and_options(gym_envs):
    env = gym_envs["MARA"]
    obs_a, _ = env.reset(seed=3)
    obs_b, _ = env.reset(seed=3)
    obs_c, _ = env.reset(seed=4)
    np.testing.assert_array_equal(obs_a, obs_b)
    assert not np.allclose(obs_a[:6], obs_c[:6])  # reset_noise drawn from the seeded key
    obs_d, _ = env.reset()  # continues the key: a new episode
    assert not np.allclose(obs_c[:6], obs_d[:6])

    action = np.zeros(6, np.float32)
    assert env.step(action)[3] is False
    _, _, terminated, truncated, info = env.step(action)
    assert truncated is True and terminated is False and info["episode_length"] == HORIZON

    # Traced params through options: the target moves, nothing recompiles.
    target = np.array(mara_mjx.envs.base.DEFAULT_TARGET_POS) + [0.0, 0.0, 0.05]
    obs, _ = env.reset(seed=3, options={"target_pos": target})
    np.testing.assert_allclose(obs[6:9], obs_a[6:9] - [0.0, 0.0, 0.05], atol=1e-5)
    assert env._jit_reset._cache_size() == 1
    with pytest.raises(ValueError, match="unknown env option"):
        env.reset(options={"nope": 1})


def test_bad_actions_raise(gym_envs):
    env = gym_envs["MARA"]
    with pytest.raises(gymnasium.error.ResetNeeded):
        MaraGymEnv("MARA").step(np.zeros(6))
    env.reset(seed=0)
    cases = [
        (np.zeros(5), "shape"),
        (np.zeros((1, 6)), "shape"),
        ([0.0, 0.0, np.nan, 0.0, 0.0, 0.0], r"non-finite .* \[\[2\]\]"),
        (np.array([0, 0, 0, 0, 0, np.inf]), "non-finite"),
        (np.full(6, 1e39), "non-finite"),  # overflows float32
        (np.array(["0"] * 6), "dtype"),
        (np.array([object()] * 6), "dtype"),
        ([0.0, [1.0, 2.0]], "shape"),
        (np.zeros(6, complex), "dtype"),
    ]
    for action, match in cases:
        with pytest.raises(ValueError, match=match):
            env.step(action)
    env.step(np.zeros(6, np.float64))  # castable dtypes are fine
    env.step([0, 0, 0, 0, 0, 0])


def test_vector_env_matches_single_env_through_autoreset(gym_envs, venv):
    """MaraVectorEnv(N, "same_step") == N single envs run by the jitted env.reset/env.step
    with the keys BatchedEnv uses, including the SAME_STEP autoreset at the 2-step horizon."""
    assert isinstance(venv, MaraVectorEnv)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert venv.observation_space.shape == (N, 12)
    assert venv.action_space.shape == (N, 6)
    single = gym_envs["MARA"]
    params = single.env.default_params

    seed = 7
    obs, info = venv.reset(seed=seed)
    refs = [single._jit_reset(k, params) for k in jax.random.split(jax.random.key(seed), N)]
    np.testing.assert_allclose(obs, np.stack([r.obs for r in refs]), atol=1e-5)
    assert obs.dtype == np.float32 and info["distance"].shape == (N,)

    actions = np.random.default_rng(0).uniform(
        venv.single_action_space.low, venv.single_action_space.high, (3, N, 6)
    )
    actions = actions.astype(np.float32)
    returns = np.zeros(N)
    for t in range(3):
        obs, reward, terminated, truncated, info = venv.step(actions[t])
        refs = [single._jit_step(r, actions[t, i]) for i, r in enumerate(refs)]
        np.testing.assert_allclose(reward, [r.reward for r in refs], atol=1e-5)
        np.testing.assert_array_equal(truncated, [bool(r.truncated) for r in refs])
        assert not terminated.any()
        returns += reward
        if t == HORIZON - 1:  # the episode ends: same-step autoreset
            assert truncated.all()
            np.testing.assert_array_equal(info["_final_obs"], [True] * N)
            final = np.stack(info["final_obs"])
            np.testing.assert_allclose(final, np.stack([r.obs for r in refs]), atol=1e-5)
            ended = info["final_info"]
            np.testing.assert_allclose(ended["episode_return"], returns, atol=1e-4)
            np.testing.assert_array_equal(ended["episode_length"], [HORIZON] * N)
            np.testing.assert_allclose(
                ended["distance"], [r.metrics["distance"] for r in refs], atol=1e-5
            )
            assert "episode" not in info  # RecordEpisodeStatistics's key, left to it
            fresh = []
            for r in refs:  # BatchedEnv: split the env's key, reset with the second half
                keep, reset_key = jax.random.split(r.key)
                fresh.append(single._jit_reset(reset_key, r.params).replace(key=keep))
            refs = fresh
            assert not np.allclose(obs[:, :6], final[:, :6])
            # top-level infos describe `obs`, the new episode's first state
            np.testing.assert_array_equal(info["episode_length"], [0] * N)
            np.testing.assert_allclose(
                info["distance"], [r.metrics["distance"] for r in refs], atol=1e-5
            )
        else:
            assert truncated.sum() == 0 and "final_obs" not in info
        np.testing.assert_allclose(obs, np.stack([r.obs for r in refs]), atol=1e-5)
    assert venv._jit_step._cache_size() == 1 and single._jit_step._cache_size() == 1
    assert single._jit_reset._cache_size() == 1


def test_vector_env_bad_input(venv):
    obs_a, _ = venv.reset()  # unseeded: a random key, then continued
    obs_b, _ = venv.reset()
    assert not np.allclose(obs_a[:, :6], obs_b[:, :6])
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        venv.step(np.zeros(6, np.float32))
    bad = np.zeros((N, 6), np.float32)
    bad[1, 4] = np.nan
    with pytest.raises(ValueError, match=r"non-finite .* \[\[1, 4\]\]"):
        venv.step(bad)
    with pytest.raises(ValueError, match="dtype"):
        venv.step(np.full((N, 6), "a"))
    with pytest.raises(ValueError, match="one int"):
        venv.reset(seed="1")
    with pytest.raises(ValueError, match="list of num_envs"):
        venv.reset(seed=[1, 2])
    # a list of N seeds: env i starts from jax.random.key(seed[i]), whatever its position
    obs_list, _ = venv.reset(seed=[5, 6, 7])
    obs_perm, _ = venv.reset(seed=[7, 5, 6])
    np.testing.assert_allclose(obs_perm, obs_list[[2, 0, 1]], atol=1e-6)
    with pytest.raises(ValueError, match="autoreset_mode"):
        MaraVectorEnv("MARA", num_envs=2, autoreset_mode="disabled")
    with pytest.raises(ValueError, match="num_envs"):
        MaraVectorEnv("MARA", num_envs=0)


def test_vector_env_next_step_matches_single_env(gym_envs, venv_next):
    """NEXT_STEP (the default): the ending step returns the final observation; the next
    step ignores the action and returns the fresh episode's first observation, reward 0."""
    assert venv_next.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    single = gym_envs["MARA"]
    obs, _ = venv_next.reset(seed=3)
    keys = jax.random.split(jax.random.key(3), N)
    refs = [single._jit_reset(k, single.env.default_params) for k in keys]
    actions = np.random.default_rng(1).uniform(-0.5, 0.5, (4, N, 6)).astype(np.float32)
    for t in range(4):
        obs, reward, terminated, truncated, info = venv_next.step(actions[t])
        if t == HORIZON:  # the step after the end: reset, action ignored
            fresh = []
            for r in refs:
                keep, reset_key = jax.random.split(r.key)
                fresh.append(single._jit_reset(reset_key, r.params).replace(key=keep))
            refs = fresh
            np.testing.assert_array_equal(reward, np.zeros(N))
            assert not (terminated | truncated).any()
            np.testing.assert_array_equal(info["episode_length"], [0] * N)
        else:
            refs = [single._jit_step(r, actions[t, i]) for i, r in enumerate(refs)]
            np.testing.assert_allclose(reward, [r.reward for r in refs], atol=1e-5)
            np.testing.assert_array_equal(truncated, [t == HORIZON - 1] * N)
        np.testing.assert_allclose(obs, np.stack([r.obs for r in refs]), atol=1e-5)
        np.testing.assert_allclose(
            info["distance"], [r.metrics["distance"] for r in refs], atol=1e-5
        )
        assert "final_obs" not in info


def test_vector_env_under_gymnasium_wrappers(venv_next):
    """gymnasium's own vector wrappers stacked as CleanRL does, across episode ends."""
    from gymnasium.wrappers import vector as wrappers

    envs = wrappers.RecordEpisodeStatistics(venv_next)
    envs = wrappers.NormalizeObservation(envs)
    envs = wrappers.NormalizeReward(envs)
    envs = wrappers.ClipAction(envs)
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (N, 12)
    ended = 0
    for _ in range(3 * (HORIZON + 1)):
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(reward))
        if (terminated | truncated).any():
            ended += 1
            episode = info["episode"]
            np.testing.assert_array_equal(episode["l"][info["_episode"]], [HORIZON] * N)
            assert np.all(episode["t"][info["_episode"]] >= 0)
    assert ended == 3
    assert len(venv_stats(envs).return_queue) == 3 * N


def venv_stats(envs):
    """The RecordEpisodeStatistics layer of a wrapper stack."""
    while not hasattr(envs, "return_queue"):
        envs = envs.env
    return envs


def test_user_registered_env_gets_a_gym_id():
    name = "MARAShortTest"
    if name not in mara_mjx.registered():
        short = {"max_episode_steps": 5}
        mara_mjx.register(name, lambda **kw: mara_mjx.make("MARA", **{**short, **kw}))
    spec = gymnasium.spec(gym_id(name))
    assert spec.kwargs == {"task": name}
    env = gymnasium.make(gym_id(name), check_target=False)
    assert env.unwrapped.max_episode_steps == 5
