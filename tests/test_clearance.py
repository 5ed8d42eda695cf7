"""The deployed collision guard (mara_mjx/envs/clearance.py, PolicyConfig.collision_guard_mm):
a step whose landing posture would touch is shortened to keep the margin, a clear step is
left alone, a posture already inside the margin may still move, and the guard exists only
in the deployed policy. The two steps are the ones MARACollisionOrient's seed 1010 took into
the table (benchmarks/NOTES.md section 38)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_export_plots import make_run

from mara_mjx.cli.export import ExportError, export_policy
from mara_mjx.envs.clearance import clearance, keep_clear
from mara_mjx.ppo.config import EvalConfig, TrainConfig
from mara_mjx.ppo.networks import make_network
from mara_mjx.ppo.parametrisation import PolicyConfig
from mara_mjx.ppo.presets import PRESETS

# observed joints, then the commanded ones, of seed 1010's two collisions 150 mm out
Q = np.array([[1.909, -0.2626, 0.6585, -0.143, 2.0652, 0.0151],
              [1.9327, -0.4802, 0.3966, -0.0321, 2.1456, 0.0737]], np.float32)  # fmt: skip
A = np.array([[1.6084, -0.8043, 0.7576, -0.0803, 2.0316, 0.2648],
              [1.7356, -0.9115, 0.7734, -0.1306, 2.0081, 0.2481]], np.float32)  # fmt: skip
MARGIN = 0.005
# a jump whose two ends are clear and whose straight line (its midpoint) is in the table
SWEEP = np.array([[1.899, -1.2646, -1.8038, -1.065, -2.4605, -2.9596],
                  [1.0918, -1.7755, -0.8027, -0.4672, -2.56, -1.5814]], np.float32)  # fmt: skip


@pytest.fixture(scope="module")
def guard():
    return jax.jit(lambda q, dq: keep_clear(q, dq, MARGIN))


def test_a_step_into_the_table_stops_short_keeping_the_margin(guard):
    assert np.all(clearance(jnp.asarray(A)) < 0) and np.all(clearance(jnp.asarray(Q)) > MARGIN)
    dq = np.asarray(guard(Q, A - Q))
    alpha = dq / (A - Q)
    assert np.allclose(alpha, alpha[:, :1], rtol=1e-5)  # the same direction, shorter
    assert np.all((alpha[:, 0] > 0.5) & (alpha[:, 0] < 1.0))  # most of the way, not all
    assert np.all(np.asarray(clearance(jnp.asarray(Q + dq))) >= MARGIN)


def test_a_clear_step_is_unchanged_and_a_close_posture_may_still_move(guard):
    half = 0.3 * (A - Q)  # the first part of the same steps: clear of everything
    assert np.all(np.asarray(clearance(jnp.asarray(Q + half))) > MARGIN)
    np.testing.assert_array_equal(np.asarray(guard(Q, half)), half)
    # from a posture 1-4 mm from the table (inside the margin) the arm may move away or
    # along, never closer than it is
    dq = np.asarray(guard(Q, A - Q))
    f = np.linspace(1.0, 1.2, 201)[:, None, None]  # a little past the guard's stop
    c = np.asarray(clearance(jnp.asarray(Q + f * dq)))  # (201, 2)
    first = np.argmax((c > 0) & (c < 0.5 * MARGIN), axis=0)
    close = (Q + f[first, 0] * dq).astype(np.float32)
    now = np.asarray(clearance(jnp.asarray(close)))
    assert np.all((now > 0) & (now < MARGIN))
    back = np.asarray(guard(close, Q - close))  # away from the table: allowed whole
    np.testing.assert_array_equal(back, Q - close)
    deeper = np.asarray(guard(close, A - close))
    assert np.all(np.asarray(clearance(jnp.asarray(close + deeper))) >= now - 1e-6)


def test_the_guard_is_deployed_only_and_checked():
    config = PRESETS["orient_first"]
    assert config.policy.collision_guard_mm == 5.0
    assert make_network(config, 6, training=True).collision_guard == 0.0
    assert make_network(config, 6).collision_guard == pytest.approx(0.005)
    with pytest.raises(ValueError, match="collision_guard_mm=-1"):
        PolicyConfig(relative_actions=True, collision_guard_mm=-1.0)
    with pytest.raises(ValueError, match="needs relative_actions=true"):
        PolicyConfig(collision_guard_mm=5.0)
    with pytest.raises(ValueError, match="collision_guard_mm=200"):
        EvalConfig(collision_guard_mm=200.0)
    assert (
        TrainConfig.of(relative_actions=True, collision_guard_mm=3.0).flat()["collision_guard_mm"]
        == 3.0
    )


def test_npz_export_refuses_a_guarded_policy(tmp_path):
    run = make_run(tmp_path / "run", "MARACollision", True, relative=True, collision_guard_mm=5.0)
    with pytest.raises(ExportError, match="collision_guard_mm=5.0.*contact distances"):
        export_policy(run, tmp_path / "policy.npz")
    assert not (tmp_path / "policy.npz").exists()


def test_the_training_clearance_penalty_charges_postures_inside_the_margin():
    import types

    import mara_mjx
    from mara_mjx.ppo.curriculum import CurriculumConfig, make_schedule, resolve

    env = mara_mjx.make("MARACollision")
    config = CurriculumConfig(train_clearance_penalty=2.0, train_clearance_mm=10.0)
    schedule = make_schedule(config, env, mara_mjx.BatchedEnv(env, 3), 10)
    dq = np.asarray(jax.jit(lambda q, d: keep_clear(q, d, 0.003))(Q, A - Q))
    near = Q[:1] + dq[:1]  # 3-4 mm from the table
    c = float(clearance(jnp.asarray(near))[0])
    assert 0.003 <= c < 0.010
    q = np.concatenate([Q[:1], near, np.zeros((1, 6), np.float32)])  # clear, near, upright
    obs = np.concatenate([q, np.zeros((3, 6), np.float32)], 1)
    traj = types.SimpleNamespace(obs=jnp.asarray(obs), final_obs=jnp.asarray(obs), metrics={})
    reward = jnp.zeros(3)
    shaped = np.asarray(schedule.shaped_reward(reward, traj, None, jnp.asarray(0)))
    np.testing.assert_allclose(shaped, [0.0, -2.0 * (1.0 - c / 0.010), 0.0], atol=1e-5)
    # a jump between two postures 69 and 47 mm clear whose straight line passes 7.5 mm
    # through the table: charged by the points on the way, not by its ends
    obs = np.concatenate([SWEEP[:1], np.zeros((1, 6), np.float32)], 1)
    landed = np.concatenate([SWEEP[1:], np.zeros((1, 6), np.float32)], 1)
    ends = jnp.asarray(SWEEP)
    assert np.all(np.asarray(clearance(ends)) > 0.04) and float(clearance(ends.mean(0))) < 0
    traj = types.SimpleNamespace(obs=jnp.asarray(obs), final_obs=jnp.asarray(landed), metrics={})
    for points, charged in ((1, False), (4, True)):
        config = config.replace(train_clearance_points=points, train_clearance_path="line")
        schedule = make_schedule(config, env, mara_mjx.BatchedEnv(env, 1), 10)
        shaped = float(schedule.shaped_reward(jnp.zeros(1), traj, None, jnp.asarray(0))[0])
        assert (shaped < -2.0) if charged else (shaped == 0.0), (points, shaped)
    with pytest.raises(ValueError, match="train_clearance_points"):
        CurriculumConfig(train_clearance_penalty=1.0, train_clearance_points=0)
    with pytest.raises(ValueError, match="train_clearance_mm=0"):
        CurriculumConfig(train_clearance_penalty=1.0, train_clearance_mm=0.0)
    with pytest.raises(ValueError, match="MARA arm"):
        resolve(config, types.SimpleNamespace(observation_layout=[], action_size=2))


def test_capped_envs_move_at_a_servos_pace_and_the_others_jump():
    """CurriculumConfig.train_capped_fraction: the last half of the rollout's envs move
    each joint at most train_capped_step per step; the first half jump as the train driver
    does (an initial policy's samples move joints by tenths of a radian)."""
    import mara_mjx
    from mara_mjx.ppo import make_train

    env = mara_mjx.make("MARACollision")
    config = PRESETS["default"].replace(
        num_envs=4, num_steps=3, num_minibatches=1, update_epochs=1, total_timesteps=4 * 3,
        train_capped_fraction=0.5, train_capped_step=0.02,
    )  # fmt: skip
    trainer = make_train(env, config, updates_per_call=1, devices=1)
    init = trainer.init(jax.random.key(0))
    q0 = np.asarray(init.env_state.env_state.q)
    state, _ = trainer.run(init, 1)
    moved = np.abs(np.asarray(state.env_state.env_state.q) - q0).max(-1)  # 3 steps
    assert np.all(moved[2:] <= 3 * 0.02 + 1e-3), moved  # offsets/noise: none without randomize
    assert np.all(moved[:2] > 0.1), moved
    with pytest.raises(ValueError, match="train_capped_fraction"):
        TrainConfig.of(train_capped_fraction=1.5)


# MARACollisionOrient's deployed last approach (the IK step, orient-first) from a posture
# 5.0 mm from a contact, 60 mm and 49 deg from the target, whose step heads into it
# (benchmarks/NOTES.md section 52: the guard used to stop the arm there for good)
FROZEN_Q = np.array([-1.429439, 0.486459, -1.109655, -0.310244, -1.670758, 2.482117], np.float32)
FROZEN_DQ = np.array([-0.022224, -0.027113, -0.032855, 0.089119, 0.01211, -0.25], np.float32)


def test_a_step_blocked_from_its_start_slides_along_the_margin(guard):
    """Every fraction of the step (down to the bisection's 1/256) comes closer to the
    contact than the arm is: shortening alone would leave it standing, and a deterministic
    policy would ask the same step again. The guard slides instead: a step of most of the
    joint motion asked, without its part toward the contact, that keeps the clearance."""
    here = float(clearance(jnp.asarray(FROZEN_Q)))
    assert MARGIN <= here < MARGIN + 1e-4  # on the margin
    assert float(clearance(jnp.asarray(FROZEN_Q + FROZEN_DQ / 256))) < MARGIN  # blocked at once
    dq = np.asarray(guard(FROZEN_Q[None], FROZEN_DQ[None]))[0]
    assert np.abs(dq).max() > 0.1  # it moves (the joint asked most of, most of the way)
    assert float(clearance(jnp.asarray(FROZEN_Q + dq))) >= MARGIN
