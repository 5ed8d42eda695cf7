"""Rewards against the spec's reference values (section 4), arithmetic in comments."""

import itertools
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mara_mjx
from mara_mjx.envs import rewards
from mara_mjx.envs.rewards import RewardParams

P = RewardParams()


@pytest.mark.parametrize(
    "d, expected",
    [
        # D(0) - 1 = (1 - e^-5)/(1 - e^-5) + 10 * 1 - 1 = 10
        (0.0, 10.000),
        # (e^-0.005 - e^-5)/(1 - e^-5) = 0.99497; 10 e^-0.25 = 7.788; sum - 1 = 7.783
        (0.001, 7.783),
        (0.005, 2.840),
        (0.01, 0.772),
        (0.02, -0.028),
        (0.05, -0.223),
        (0.1, -0.396),
        (0.5, -0.924),
        # D(1) = 0 + 0 -> -1
        (1.0, -1.000),
    ],
)
def test_distance_term_reference_values(d, expected):
    r = rewards.reward(jnp.float32(d), 0.0, False, P, orientation=False, collision=False)
    assert float(r) == pytest.approx(expected, abs=1.5e-3)


@pytest.mark.parametrize(
    "d, expected",
    # C = 3 (2 min(d, 0.5))^0.03: 3 * 0.002^0.03 = 3 * e^(0.03 ln 0.002) = 2.490
    [(0.001, 2.490), (0.01, 2.668), (0.1, 2.859), (0.5, 3.000), (0.8, 3.000)],
)
def test_collision_penalty_reference_values(d, expected):
    c = rewards.collision_penalty(jnp.float32(d), True, P.delta, P.eta)
    assert float(c) == pytest.approx(expected, abs=1.5e-3)
    assert float(rewards.collision_penalty(jnp.float32(d), False, P.delta, P.eta)) == 0.0


def test_orientation_factor_reference_value():
    # O(pi/2), beta 1.5, gamma 1: (2 - 0.5^1.5) / 2 = (2 - 0.35355) / 2 = 0.8232
    assert float(rewards.orientation_factor(jnp.pi / 2, 1.5, 1.0)) == pytest.approx(
        0.8232, abs=1e-4
    )
    assert float(rewards.orientation_factor(0.0, 1.5, 1.0)) == pytest.approx(1.0)
    # upside down: (1 + 1 - 1) / 2 = 0.5
    assert float(rewards.orientation_factor(jnp.pi, 1.1, 1.0)) == pytest.approx(0.5)


def test_task_compositions():
    d, theta = jnp.float32(0.01), jnp.float32(math.pi / 2)
    D = float(rewards.distance_term(d, 5.0, 0.02))
    O = float(rewards.orientation_factor(theta, 1.5, 1.0))
    C = float(rewards.collision_penalty(d, True, 3.0, 0.03))
    r = lambda o, c: float(rewards.reward(d, theta, True, P, orientation=o, collision=c))  # noqa: E731
    assert r(False, False) == pytest.approx(D - 1, rel=1e-5)
    assert r(True, False) == pytest.approx(D * O - 1, rel=1e-5)
    assert r(False, True) == pytest.approx(D - 1 - C, rel=1e-5)
    assert r(True, True) == pytest.approx(D * O - 1 - C, rel=1e-5)


def test_max_reward_is_ten_and_rms_distance():
    assert float(rewards.reward(0.0, 0.0, False, P, orientation=True, collision=True)) == (
        pytest.approx(10.0)
    )
    # RMS, not Euclidean: sqrt((9 + 16 + 0) / 3)
    assert float(rewards.rms_distance(jnp.array([3.0, 4.0, 0.0]))) == pytest.approx(
        math.sqrt(25 / 3)
    )
    # theta = 2 arccos(|w|): a 90 degree rotation about z, either sign of the quaternion
    q = np.array([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    for s in (1, -1):
        assert float(rewards.orientation_angle(jnp.asarray(s * q))) == pytest.approx(math.pi / 2)


def test_rewards_jit_and_broadcast():
    d = jnp.linspace(0, 1, 7)
    f = jax.jit(lambda d: rewards.reward(d, d, d > 0.5, P, orientation=True, collision=True))
    out = f(d)
    assert out.shape == (7,)
    assert np.all(np.isfinite(np.asarray(out)))


# Issue 34 item 6: the hyperparameters' valid ranges (mara_mjx.envs.rewards.RANGES).
BAD_VALUES = [
    ("delta", -1.0),  # a collision bonus
    ("eta", -0.1),  # infinite penalty at the target
    ("alpha", 1e300),  # inf in float32: every reward -1
    ("alpha", 0.0),
    ("alpha", 1e-8),  # 1 - exp(-alpha) = 0 in float32: NaN
    ("done", 0.0),
    ("done", 5.0),
    ("beta", 0.0),
    ("gamma", -0.5),  # O(pi) < 0
    ("eta", 3.0),
    ("beta", math.nan),
    ("gamma", math.inf),
    ("delta", -math.inf),
]


@pytest.mark.parametrize("name, value", BAD_VALUES)
def test_reward_params_reject_values_outside_their_range(name, value):
    expected = f"{name}={value!r} is outside its valid range {rewards.RANGES[name]}"
    with pytest.raises(ValueError, match=re.escape(expected)):
        RewardParams(**{name: value})
    with pytest.raises(ValueError, match=re.escape(expected)):  # numpy values too
        RewardParams(**{name: np.array([1.0, value])[1:]})


def test_make_and_make_params_reject_bad_reward_values():
    with pytest.raises(ValueError, match=r"delta=-1\.0 is outside its valid range \[0, 1e\+06\]"):
        mara_mjx.make("MARACollision", delta=-1.0, check_target=False)
    env = mara_mjx.make("MARA", check_target=False)
    with pytest.raises(ValueError, match=r"alpha=1e\+300 is outside"):
        env.make_params(alpha=1e300)
    with pytest.raises(ValueError, match=r"eta=-1\.0 is outside"):  # a jax array in a config
        env.config.replace(reward=RewardParams(eta=jnp.float32(-1.0)))


def test_range_ends_keep_float32_rewards_finite_and_varying():
    """Every corner of the ranges: finite rewards over d in [0, 2] m, theta in [0, pi],
    and D still varies with d; just past alpha's lower end float32 gives NaN."""
    d = jnp.linspace(0.0, 2.0, 201, dtype=jnp.float32)
    theta = jnp.linspace(0.0, jnp.pi, 201, dtype=jnp.float32)
    ends = {
        n: (r.low if not r.low_open else r.low + 1e-6, r.high) for n, r in rewards.RANGES.items()
    }
    for corner in itertools.product(*ends.values()):
        p = RewardParams(**dict(zip(ends, corner, strict=True)))
        p32 = jax.tree.map(jnp.float32, p)
        r = rewards.reward(d, theta, d > 1.0, p32, orientation=True, collision=True)
        assert bool(jnp.all(jnp.isfinite(r))), p
        dist = rewards.distance_term(d, p32.alpha, p32.done)
        assert float(dist[0] - dist[100]) > 0.0, p  # d = 0 beats d = 1 m
    past = rewards.distance_term(d, jnp.float32(1e-8), jnp.float32(1.0))
    assert not bool(jnp.all(jnp.isfinite(past)))


def test_traced_reward_params_are_not_checked():
    """Tracers (jit, vmap) carry no value: construction inside them must not raise."""
    batch = jax.tree.map(lambda x: jnp.full((2,), x), RewardParams())
    out = jax.jit(jax.vmap(lambda p: rewards.distance_term(0.5, p.alpha, p.done)))(batch)
    assert out.shape == (2,)


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--env.delta", "-1"], "delta=-1.0 is outside its valid range [0, 1e+06]"),
        (["--alpha", "1e300"], "alpha=1e+300 is outside its valid range [0.001, 80]"),
        (["--eta", "nan"], "eta=nan is outside its valid range [0, 1]"),
    ],
)
def test_train_cli_rejects_bad_reward_flags(flags, message, tmp_path, capsys):
    from mara_mjx.cli import train as train_cli
    from mara_mjx.cli.common import run_cli

    argv = ["--env", "MARACollision", "--out", str(tmp_path / "run"), *flags]
    assert run_cli(train_cli.main, train_cli.PROG, argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("mara_mjx.train: error:") and message in err, err
    assert err.count("\n") == 1 and not (tmp_path / "run").exists()


def test_train_reward_curriculum_start_must_be_in_range():
    from mara_mjx.ppo import make_train
    from mara_mjx.ppo.config import TrainConfig

    env = mara_mjx.make("MARA", check_target=False)
    config = TrainConfig.of(num_envs=2, num_steps=2, num_minibatches=1, total_timesteps=4)
    with pytest.raises(ValueError, match=r"train_reward: .*alpha=0\.0 is outside"):
        make_train(env, config.replace(train_reward="alpha=0"))
