"""Imitation of a trained policy (mara_mjx.ppo.teacher, CurriculumConfig.teacher): the loss,
the trainer's contract, and a student that learns a fixed teacher's actions (tiny MARA).
The CLI path (--preset distill --teacher RUN, seed by seed) is in test_seeds_cli.py."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mara_mjx
from mara_mjx.ppo.divergence import check_finite
from mara_mjx.ppo.networks import make_network
from mara_mjx.ppo.policy import make_policy
from mara_mjx.ppo.presets import PRESETS
from mara_mjx.ppo.teacher import (
    imitation_loss,
    lookahead_action,
    rollout_sigma,
    teacher_action,
)
from mara_mjx.ppo.train import make_train

TINY = dict(num_envs=16, num_steps=8, num_minibatches=2, update_epochs=2, learning_rate=3e-3)


def test_imitation_loss_is_the_gaussian_negative_log_likelihood():
    mean = jnp.array([[0.1, -0.2], [0.0, 0.3]])
    log_std = jnp.array([-1.0, -2.0])
    target = jnp.array([[0.2, -0.2], [0.5, 0.1]])
    sigma = np.exp([-1.0, -2.0])
    z = (np.asarray(target) - np.asarray(mean)) / sigma
    expected = np.mean(np.sum(0.5 * z**2 + np.log(sigma), axis=-1))
    assert float(imitation_loss(mean, log_std, target)) == pytest.approx(expected, rel=1e-6)
    # the mean's gradient vanishes on the teacher's action, the log-std's where sigma is the error
    g_mean = jax.grad(lambda m: imitation_loss(m, log_std, target))(target)
    assert np.allclose(g_mean, 0.0)
    err = jnp.array([[0.1, 0.1]])
    g_std = jax.grad(lambda s: imitation_loss(jnp.zeros((1, 2)), s, err))(jnp.log(err[0]))
    assert np.allclose(g_std, 0.0, atol=1e-6)


def test_the_imitation_spread_widens_the_rollouts_noise_env_by_env():
    """imitation_spread s: env i of N samples with max(sigma, s i / (N - 1)): env 0 with
    the student's own sigma, the last at s, none below sigma; 0 leaves sigma alone; the
    config refuses it without a teacher, naming the flag."""
    log_std = jnp.broadcast_to(jnp.log(jnp.array([0.01, 0.02])), (5, 2))
    wide = np.asarray(rollout_sigma(log_std, 0.08))
    np.testing.assert_allclose(wide[:, 0], [0.01, 0.02, 0.04, 0.06, 0.08], rtol=1e-6)
    np.testing.assert_allclose(wide[:, 1], [0.02, 0.02, 0.04, 0.06, 0.08], rtol=1e-6)
    np.testing.assert_allclose(rollout_sigma(log_std, 0.0), np.exp(log_std), rtol=1e-6)
    with pytest.raises(ValueError, match="imitation_spread .*--teacher RUN"):
        PRESETS["distill"].replace(imitation_spread=0.05)
    with pytest.raises(ValueError, match="imitation_spread"):
        PRESETS["distill"].replace(teacher="runs/x", imitation_spread=-0.1)


class _State(NamedTuple):
    obs: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    metrics: dict


def _toy_step(state, action):
    """A toy world: the joints are where the action puts them, the position error is the
    first three joints (m); joint 6 in (0.2, 0.3) ends the episode (terminated), in (0.6,
    0.7) truncates it, joint 5 in (0.2, 0.3) collides."""
    q = action
    inside = lambda j, lo: (q[:, j] > lo) & (q[:, j] < lo + 0.1)  # noqa: E731
    collided = inside(4, 0.2).astype(jnp.float32)
    return _State(obs_of(q), inside(5, 0.2), inside(5, 0.6), {"collided": collided})


def obs_of(q):
    return jnp.concatenate([q, q[:, :3]], -1)


def _toy_state(rows):
    q = jnp.array([r + [0.0] * (6 - len(r)) for r in rows])
    zeros = jnp.zeros(len(rows), bool)
    return q, _State(obs_of(q), zeros, zeros, {"collided": jnp.zeros(len(rows))})


def test_the_lookahead_label_is_where_the_teacher_arrives_near_the_target():
    """imitation_lookahead k: within the radius the label is the teacher's action k - 1
    steps ahead (its joints after k steps), while every state on the way is inside the
    radius and no step ends the episode or collides; outside, the teacher's own action."""
    halve = lambda obs: 0.5 * obs[:, :6]  # noqa: E731
    q, state = _toy_state(
        [
            [0.01],  # inside 20 mm: three steps ahead
            [0.03],  # 30 mm: outside, the teacher's action
            [0.036],  # inside 40 mm; next 18 mm, then 9
            [0.01, 0, 0, 0, 0, 0.5],  # its first step ends the episode (0.25)
            [0.01, 0, 0, 0, 0, 0.9],  # its second does (0.45, then 0.225)
            [0.01, 0, 0, 0, 0, 1.3],  # its first step truncates it (0.65)
            [0.01, 0, 0, 0, 0.5],  # its first step collides (joint 5 at 0.25)
        ]
    )
    lo, hi = -jnp.inf, jnp.inf
    np.testing.assert_allclose(lookahead_action(halve, _toy_step, state, lo, hi, 1, 0.02), q / 2)
    got = np.asarray(lookahead_action(halve, _toy_step, state, lo, hi, 3, 0.02))
    np.testing.assert_allclose(got, q / np.array([8, 2, 2, 2, 4, 2, 2])[:, None])
    wide = np.asarray(lookahead_action(halve, _toy_step, state, lo, hi, 3, 0.04))
    np.testing.assert_allclose(wide[:3], q[:3] / 8)
    # a teacher heading out of the radius: its next state (22.5 mm) is outside 20
    grow = lambda obs: 1.5 * obs[:, :6]  # noqa: E731
    q, state = _toy_state([[0.015]])
    np.testing.assert_allclose(lookahead_action(grow, _toy_step, state, lo, hi, 3, 0.02), 1.5 * q)
    # the steps ahead take the clipped action: a teacher overshooting to -2 q in a box of
    # +-15 mm stays within 30 mm (-15, +15, -15: the label -15 mm); unclipped, its second
    # state would be 40 mm off, outside, and the label +15 mm
    flip = lambda obs: -2.0 * obs[:, :6]  # noqa: E731
    q, state = _toy_state([[0.01]])
    box = np.asarray(lookahead_action(flip, _toy_step, state, -0.015, 0.015, 3, 0.03))
    np.testing.assert_allclose(box[0, 0], -0.015)
    with pytest.raises(ValueError, match="imitation_lookahead .*--teacher RUN"):
        PRESETS["distill"].replace(imitation_lookahead=2)
    with pytest.raises(ValueError, match="imitation_lookahead_mm"):
        PRESETS["distill"].replace(teacher="runs/x", imitation_lookahead_mm=0.0)


def _teacher(env):
    """A fixed policy to imitate: a fresh network of the default preset whose actor's
    output weights are scaled up (a fresh actor's joint deltas are near 0, as a fresh
    student's: nothing to learn), its obs statistics those of no data (mean 0, var 1)."""
    config = PRESETS["default"]
    network = make_network(config, env.action_size)
    obs = jnp.zeros((env.observation_size,))
    params = network.init(jax.random.key(7), obs, obs)
    out = params["params"]["actor"]["Dense_2"]
    out = {"kernel": 30.0 * out["kernel"], "bias": out["bias"] + 0.2}
    params = {
        "params": {**params["params"], "actor": {**params["params"]["actor"], "Dense_2": out}}
    }
    from mara_mjx.ppo.networks import RunningStats

    return make_policy(params, config, RunningStats.create(env.observation_size))


def test_make_train_needs_the_teacher_and_its_path_together():
    env = mara_mjx.make("MARA")
    with pytest.raises(ValueError, match="make_train\\(..., teacher="):
        make_train(env, PRESETS["distill"].replace(teacher="runs/x", **TINY))
    with pytest.raises(ValueError, match="config's teacher is ''"):
        make_train(env, PRESETS["distill"].replace(**TINY), teacher=_teacher(env))
    with pytest.raises(ValueError, match="population > 1 do not combine"):
        PRESETS["distill"].replace(teacher="runs/x", population=2)


def test_a_student_learns_its_teachers_actions():
    """20 updates of imitation on tiny MARA, half the envs exploring wider than the
    student's sigma (imitation_spread): the student's deterministic action comes closer to
    the teacher's on the states the student visits, its own sigma shrinks toward that
    error (the spread widens the rollouts, not the loss's sigma), the teacher itself is
    never trained, and the state's teacher is the one given."""
    env = mara_mjx.make("MARA")
    teacher = _teacher(env)
    config = PRESETS["distill"].replace(
        teacher="a fixed network", init_log_std=-1.0, imitation_spread=0.8, **TINY
    )
    trainer = make_train(env, config, updates_per_call=10, teacher=teacher)
    state = trainer.init(jax.random.key(0))
    lower, upper = env.joint_lower, env.joint_upper

    def gap(state):
        obs = state.env_state.obs
        student = make_policy(state.params, trainer.config, state.obs_stats)
        target = teacher_action(teacher, obs, lower, upper)
        return float(jnp.sqrt(jnp.mean(jnp.square(student(obs) - target))))

    before = gap(state)
    state, m1 = trainer.run(state, 10)
    state, m2 = trainer.run(state, 10)
    after = gap(state)
    assert after < 0.5 * before, (before, after)
    assert float(m2["loss"][-1]) < float(m1["loss"][0])
    log_std = np.asarray(state.params["params"]["log_std"])
    assert np.all(log_std < -1.0)  # sigma shrank from its initial e^-1 with the error
    for a, b in zip(jax.tree.leaves(state.teacher), jax.tree.leaves(teacher), strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_wide_spread_over_a_narrow_student_trains_without_a_false_divergence():
    """The rollouts sample far outside a narrow student's sigma (spread 0.8 rad over
    sigma e^-8): PPO's clip loss on those samples overflows (its ratio exp(log pi -
    log pi_old) is inf), but imitation does not train on it. The losses the divergence
    guard reads are the imitation's and finite; the run is not stopped (GPU study 61
    stopped every student at update ~160 on that unused loss)."""
    env = mara_mjx.make("MARA")
    config = PRESETS["distill"].replace(
        teacher="a fixed network",
        init_log_std=-8.0,
        log_std_floor=-8.0,
        imitation_spread=0.8,
        imitation_lookahead=3,  # (and labels three steps ahead near the target)
        imitation_lookahead_mm=500.0,
        **TINY,
    )
    trainer = make_train(env, config, updates_per_call=2, teacher=_teacher(env))
    state, metrics = trainer.run(trainer.init(jax.random.key(0)), 2)
    check_finite(state, metrics, 0, 2)  # raises Diverged on a non-finite loss
    for k in ("loss", "policy_loss", "value_loss", "approx_kl", "clip_frac"):
        assert np.all(np.isfinite(np.asarray(metrics[k]))), k
    # the policy's loss of an imitation run is the imitation loss
    np.testing.assert_array_equal(metrics["policy_loss"], metrics["loss"])


def test_a_single_student_run_takes_the_teacher_seed_of_its_own_seed(tmp_path):
    """A teacher run of several seeds teaches a single student run (no --seeds) from the
    seed folder of the student's seed; without one, a clear error naming the seeds it has
    and the two ways out (nothing is loaded, so empty folders stand in for the seeds)."""
    from mara_mjx.ppo.teacher import load_teacher

    for s in (1000, 1001):
        (tmp_path / f"seed_{s}").mkdir()
    with pytest.raises(ValueError, match=r"seeds 1000, 1001 and has no seed_7 .*--seeds"):
        load_teacher(tmp_path, "MARA", seed=7)
    with pytest.raises(ValueError, match="seed_1001"):  # its own seed's folder: loaded
        load_teacher(tmp_path, "MARA", seed=1001)  # (empty here: no checkpoint in it)


def test_a_teacher_that_deploys_a_plan_teaches_its_step(tmp_path):
    """The CLI default of the Orient tasks deploys the plan and its restarts (orient_first);
    as a teacher it acts one step at a time: the loaded policy has neither, and its action
    is the saved policy's own step, not the 16-step landing its deployment commands."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_export_plots import make_run

    from mara_mjx.ppo.teacher import load_teacher

    run = make_run(tmp_path / "run", "MARAOrient", True, relative=True,
                   ik_prior="residual", ik_gate=0.1, plan_steps=16, plan_starts=2)  # fmt: skip
    deployed = make_policy(str(run))
    teacher = load_teacher(run, "MARAOrient")
    assert deployed.config.policy.plan_steps == 16 and deployed.config.policy.plan_starts == 2
    assert teacher.config.policy.plan_steps == 0 and teacher.config.policy.plan_starts == 0
    obs = mara_mjx.make("MARAOrient").reset(jax.random.key(0)).obs[None]
    step = deployed.distribution(obs)[0]
    np.testing.assert_array_equal(teacher(obs), step)
    assert not np.allclose(deployed(obs), step, atol=1e-3)  # the plan's landing differs
