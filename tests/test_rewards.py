"""Rewards against the spec's reference values (section 4), arithmetic in comments."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mara_mjx import rewards
from mara_mjx.rewards import RewardParams

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
