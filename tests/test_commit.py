"""PolicyConfig.commit_rad (deploy/numpy_policy.committed): the deployed policy holds each
command until the arm arrives or stops. The rule itself in numpy and jax.numpy; on the
train driver (every command carried out within a step) the evaluation is unchanged; on
the real driver the evaluation loop holds commands exactly as the robot-side runner does
with the exported file, and the held commands differ from re-asking every step."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_export_plots import make_run

import mara_mjx
from mara_mjx.cli.export import export_policy
from mara_mjx.deploy import in_the_loop
from mara_mjx.deploy.numpy_policy import COMMIT_STALL_RAD, committed
from mara_mjx.deploy.runner import PolicyRunner
from mara_mjx.ppo import PolicyConfig, make_policy
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import episode_plan, evaluate

LO, HI = -np.ones(6), np.ones(6)


def test_the_rule_holds_a_command_until_the_arm_arrives_or_stops():
    q = np.zeros((4, 6))
    held = np.zeros((4, 6))
    held[:, 2] = [0.5, 0.5, 0.005, 0.5]  # far, far, arrived, far
    previous = q.copy()
    previous[:2, 2] = -0.02  # rows 0-1 moved 0.02 rad in the last period
    previous[3, 2] = -COMMIT_STALL_RAD / 2  # row 3 has stopped short
    new = np.full((4, 6), 0.2)
    new[1, 0] = 3.0  # clipped where chosen
    want = np.stack([held[0], held[1], new[2], new[3]])
    got = committed(q, new, held, previous, 0.01, LO, HI)
    np.testing.assert_array_equal(got, want)
    got_jax = committed(*map(jnp.asarray, (q, new, held, previous)), 0.01, LO, HI, xp=jnp)
    np.testing.assert_allclose(np.asarray(got_jax), want, atol=1e-7)
    new[0, 0] = 3.0  # arrived at a clipped command: the clip is what counts
    assert committed(q, new, q, q, 0.01, LO, HI)[0, 0] == 1.0


def test_bad_commit_rad_is_refused_with_the_valid_range():
    for bad in (-0.1, 0.6, float("nan")):
        with pytest.raises(ValueError, match=r"commit_rad=.* must be a finite number in \[0"):
            PolicyConfig(commit_rad=bad)
    with pytest.raises(ValueError, match=r"commit_rad must be -1 \(as trained\) or"):
        EvalConfig(commit_rad=-2.0)


@pytest.fixture(scope="module")
def orient(tmp_path_factory):
    """An untrained MARAOrient policy (joint steps up to 0.05 rad: several servo periods
    at 0.3 rad/s) and its .npz export with commit_rad 0.01."""
    tmp = tmp_path_factory.mktemp("commit")
    run = make_run(tmp / "run", "MARAOrient", True, seed=6, relative=True, max_joint_step=0.05)
    path = export_policy(run, tmp / "policy.npz", commit_rad=0.01)
    return make_policy(run), path


def test_the_train_driver_is_unchanged(orient):
    policy, _ = orient
    env = mara_mjx.make("MARAOrient", max_episode_steps=30)
    base = EvalConfig(episodes=4, tolerance_mm=0.0, noise=0.3)
    off = evaluate(env, policy, base.replace(commit_rad=0.0))
    on = evaluate(env, policy, base.replace(commit_rad=0.01))
    # (two programs: float32 rounding apart)
    np.testing.assert_allclose(on.position_error_mm, off.position_error_mm, atol=1e-3)
    np.testing.assert_allclose(on.orientation_error_deg, off.orientation_error_deg, atol=1e-3)


def test_evaluate_holds_commands_as_the_runner_does(orient):
    """`evaluate policy.npz` on the real driver (the file's commit_rad, applied by the
    evaluation loop) ends each episode where the runner, stepping the same env with the
    same file, ends it; the runner without the rule ends elsewhere."""
    _, path = orient
    export = in_the_loop.load(path)
    assert in_the_loop.commit_rad(export.meta) == 0.01
    horizon = 24
    env = in_the_loop.make_env(export, driver="real", velocity=0.3, max_episode_steps=horizon)
    config = EvalConfig(episodes=2, tolerance_mm=0.0, noise=0.2, commit_rad=0.01)
    result = evaluate(env, export.policy, config)
    params, keys = episode_plan(env, config)
    step = jax.jit(env.step)
    for i in range(config.episodes):
        ends = []
        for rule in (0.01, 0.0):
            runner = PolicyRunner.load(path)
            runner.commit_rad = rule
            rows = []  # the observations the file was run on, per step
            act = runner._policy
            runner._policy = lambda obs, act=act, rows=rows: rows.append(len(obs)) or act(obs)
            state = env.reset(keys[i], params)
            held = 0
            for _ in range(horizon):
                before = runner._held
                action = runner.step(
                    np.asarray(state.obs[:6]), state.params.target_pos, state.params.target_quat
                )
                held += before is not None and np.array_equal(action, before[0])
                state = step(state, jnp.asarray(action, jnp.float32))
            ends.append(1e3 * np.abs(np.asarray(state.metrics["position_error"])))
            if rule:
                assert held >= 4, "no command was held"
                assert sum(rows) <= horizon - held  # a held command runs no policy
            else:
                assert sum(rows) == horizon
        np.testing.assert_allclose(ends[0], result.position_error_mm[i], atol=1e-2)
        assert np.abs(ends[1] - ends[0]).max() > 0.1
