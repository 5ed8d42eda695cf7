"""The random-target tasks: targets drawn per episode from a pose table of reachable,
collision-free poses in a configurable region; the fixed-target tasks unchanged bit for
bit; the held-out evaluation as a user runs it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import jitted, max_traces
from gymnasium.utils.env_checker import check_env

import mara_mjx
from mara_mjx import BatchedEnv
from mara_mjx.adapters.gym import gym_id
from mara_mjx.envs import ik, targets
from mara_mjx.envs.base import DEFAULT_TARGET_POS, DEFAULT_TARGET_QUAT, METRIC_KEYS
from mara_mjx.envs.random_target import (
    PARENTS,
    RANDOM_TASKS,
    TARGET_METRIC_KEYS,
    RandomTargetEnv,
    random_target_config,
    with_targets,
)
from mara_mjx.ppo import RunningStats
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.config import TrainConfig
from mara_mjx.ppo.networks import make_network
from mara_mjx.ppo.policy import load_policy

REPO = Path(__file__).resolve().parents[1]
RANDOM_NAMES = tuple(RANDOM_TASKS)
ORIENT = "MARACollisionOrientRandomTarget"


# ------------------------------------------------------------------ the four tasks
def test_registered_with_gym_ids():
    assert set(RANDOM_NAMES) == {
        "MARARandomTarget",
        "MARAOrientRandomTarget",
        "MARACollisionRandomTarget",
        "MARACollisionOrientRandomTarget",
    }
    assert set(RANDOM_NAMES) <= set(mara_mjx.registered())
    for name in RANDOM_NAMES:
        assert gym_id(name) in gymnasium.registry


# The task with both flags (orientation, collision penalty) off and the one with both on:
# each flag's two branches; their programs are the ones the other tests here compile.
@pytest.mark.parametrize("name", ["MARARandomTarget", ORIENT])
def test_random_task_matches_its_parent_at_the_drawn_target(name):
    """Same observation layout and reward as the fixed parent given the same target."""
    j, jp = jitted(name), jitted(PARENTS[name])
    env, parent = j.env, jp.env
    assert (env.observation_size, env.task.orientation, env.task.collision_penalty) == (
        parent.observation_size,
        parent.task.orientation,
        parent.task.collision_penalty,
    )
    assert env.config.reward == parent.config.reward  # the parent's beta
    s = j.reset(jax.random.key(3))
    assert set(s.metrics) == set(METRIC_KEYS + TARGET_METRIC_KEYS)
    target = np.asarray(s.params.target_pos)
    np.testing.assert_array_equal(np.asarray(s.metrics["target_pos"]), target)
    np.testing.assert_array_equal(
        np.asarray(s.metrics["target_quat"]), np.asarray(s.params.target_quat)
    )
    action = jnp.array([1.0, -1.2, -0.6, 0.3, 2.0, -0.2])
    s1 = j.step(s, action)
    np.testing.assert_array_equal(np.asarray(s1.metrics["target_pos"]), target)  # kept
    p = parent.default_params.replace(target_pos=s.params.target_pos)
    p = p.replace(target_quat=s.params.target_quat)
    ps = jp.step(jp.reset(jax.random.key(0), p).replace(q=s.q, qvel=s.qvel), action)
    np.testing.assert_allclose(np.asarray(s1.obs), np.asarray(ps.obs), rtol=1e-5, atol=1e-6)
    assert float(s1.reward) == pytest.approx(float(ps.reward), rel=1e-5, abs=1e-6)
    e = np.asarray(s1.obs[6:9])
    tcp = env.arm.mj_data(np.asarray(action)).site_xpos[env.arm.tcp_site]
    np.testing.assert_allclose(e, tcp - target, atol=2e-5)  # e is relative to the draw


def test_targets_differ_across_resets_and_keys():
    j = jitted(ORIENT)
    env = j.env
    keys = jax.random.split(jax.random.key(0), 16)
    states = jax.jit(jax.vmap(env.reset))(keys)
    pos = np.asarray(states.params.target_pos)
    assert len({tuple(p) for p in pos.round(6)}) >= 14  # 16 draws from 1024 poses
    again = j.reset(keys[5])
    np.testing.assert_array_equal(np.asarray(again.params.target_pos), pos[5])  # per key
    other = j.reset(jax.random.key(1))
    assert not np.array_equal(np.asarray(other.params.target_pos), pos[0])
    # every drawn target is a row of the table
    table = np.asarray(env.default_params.table_pos)
    assert all(np.any(np.all(table == p, axis=1)) for p in pos)


class _Counting(RandomTargetEnv):
    """The random-target reset with a step that only counts (no physics to compile):
    BatchedEnv's auto-reset is what is under test here."""

    def step(self, state, action):
        step = state.step + 1
        return state.replace(step=step, truncated=step >= self.config.max_episode_steps)


def test_auto_reset_draws_a_new_target():
    task = RANDOM_TASKS[ORIENT]
    env = _Counting(task, random_target_config(task).replace(max_episode_steps=2))
    benv = BatchedEnv(env, 8, devices=1)
    s0 = jax.jit(benv.reset)(jax.random.key(0))
    a = jnp.zeros((8, 6))
    step = jax.jit(max_traces(benv.step))
    s1 = step(s0, a)
    s2 = step(s1, a)
    assert not np.any(np.asarray(s1.truncated)) and np.all(np.asarray(s2.truncated))
    before = np.asarray(s0.env_state.params.target_pos)
    np.testing.assert_array_equal(np.asarray(s1.env_state.params.target_pos), before)
    after = np.asarray(s2.env_state.params.target_pos)
    assert np.sum(np.any(before != after, axis=1)) >= 7
    np.testing.assert_array_equal(np.asarray(s2.env_state.metrics["target_pos"]), after)
    # the table itself is carried unchanged
    np.testing.assert_array_equal(
        np.asarray(s2.env_state.params.table_pos), np.asarray(s0.env_state.params.table_pos)
    )


# ------------------------------------------------------------------ the pose table
def test_default_region_holds_the_spec_target_and_is_covered():
    env = jitted(ORIENT).env
    region = env.region
    assert region.contains(np.array(DEFAULT_TARGET_POS), np.array(DEFAULT_TARGET_QUAT))[0]
    assert env.config.target_spread_deg == 30.0
    assert mara_mjx.make("MARARandomTarget").config.target_spread_deg == 180.0
    # every cell of a 5 x 5 x 5 grid over the default box holds candidate poses
    pool = targets.candidates(env.arm.mj_model, region, 4096, seed=0)
    low, high = np.array(region.low), np.array(region.high)
    cell = np.clip(((pool.pos - low) / (high - low) * 5).astype(int), 0, 4)
    assert len({tuple(c) for c in cell}) == 125


def test_table_poses_are_in_region_collision_free_and_reachable():
    env = jitted(ORIENT).env
    table = env.pose_table()
    region = env.region
    assert len(table) == env.config.target_table_size == 1024
    assert np.all(region.contains(table.pos, table.quat))
    assert np.all(table.q >= env.arm.lower) and np.all(table.q <= env.arm.upper)
    np.testing.assert_allclose(np.asarray(env.default_params.table_pos), table.pos, atol=1e-6)
    m = env.arm.mj_model
    d = mujoco.MjData(m)
    for i in range(0, len(table), 8):  # C MuJoCo: the stored pose is the FK of q, no contact
        d.qpos[:] = table.q[i]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        np.testing.assert_allclose(d.site_xpos[env.arm.tcp_site], table.pos[i], atol=1e-12)
        quat = d.xquat[env.arm.flange_body]
        assert abs(abs(quat @ table.quat[i]) - 1.0) < 1e-12
        assert not np.any(d.contact.dist[: d.ncon] < 0)
    # inverse kinematics finds a collision-free solution for a sample of them
    # (64 starts: from 16, one of these poses ends at a joint limit 10 mm away)
    for i in np.random.default_rng(0).choice(len(table), 4, replace=False):
        res = ik.solve(m, table.pos[i], table.quat[i], seeds=64)
        assert not res.collided and res.position_error < 1e-3
        assert res.angle_error < np.radians(1.0)
    # about balanced over the box: no 2 x 2 x 2 octant holds more than 3x another's poses
    octant = ((table.pos - region.low) / (np.subtract(region.high, region.low)) * 2).astype(int)
    counts = np.bincount(np.ravel_multi_index(np.clip(octant, 0, 1).T, (2, 2, 2)), minlength=8)
    assert counts.min() > 0 and counts.max() < 3 * counts.min()


def test_orientation_spread_is_respected_and_filled():
    env = jitted(ORIENT).env
    angles = np.degrees(targets.angle_to(env.pose_table().quat, DEFAULT_TARGET_QUAT))
    assert angles.max() <= 30.0 + 1e-4 and np.percentile(angles, 90) > 20.0
    narrow = env.pose_table(env.config.replace(target_spread_deg=5.0))
    angles = np.degrees(targets.angle_to(narrow.quat, DEFAULT_TARGET_QUAT))
    assert angles.max() <= 5.0 + 1e-4 and angles.max() > 3.0


def test_region_change_through_params_does_not_recompile():
    j = jitted(ORIENT)
    env = j.env
    reset = jax.jit(max_traces(env.reset, n=1))
    s = reset(jax.random.key(0), env.default_params)
    low, high = (-0.35, -0.05, 0.75), (-0.30, 0.05, 0.80)
    p = env.make_params(target_min=low, target_max=high, target_spread_deg=10.0)
    keys = jax.random.split(jax.random.key(1), 8)
    pos = np.stack([np.asarray(reset(k, p).params.target_pos) for k in keys])
    assert np.all(pos >= np.array(low) - 1e-6) and np.all(pos <= np.array(high) + 1e-6)
    assert not np.all(np.asarray(s.params.target_pos) >= np.array(low))  # it moved
    s1 = j.step(reset(keys[0], p), jnp.zeros(6))  # the session's compiled step serves it
    assert np.all(np.isfinite(np.asarray(s1.obs)))
    # make() with the same override gives the same table
    made = mara_mjx.make(ORIENT, target_min=low, target_max=high, target_spread_deg=10.0)
    np.testing.assert_array_equal(
        np.asarray(made.default_params.table_pos), np.asarray(p.table_pos)
    )


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"target_min": (0.0, 0.0, 1.0), "target_max": (0.1, 0.1, 0.9)}, r"target_min=.* below"),
        ({"target_min": (0.0, 0.0)}, r"target_min must have shape \(3,\)"),
        ({"target_max": (0.0, np.nan, 1.0)}, "target_max=.* must be finite"),
        ({"target_spread_deg": 200.0}, r"target_spread_deg=200.0 must be in \[0, 180\]"),
        ({"target_spread_deg": -1.0}, "target_spread_deg"),
        ({"target_table_size": 0}, r"target_table_size=0 must be an int in \[1, 65536\]"),
        ({"target_seed": -1}, "target_seed"),
        (
            {"target_min": (-0.5, -0.2, 0.2), "target_max": (-0.3, 0.2, 0.4)},
            r"target region is empty.*target_min=\[-0.5, -0.2, 0.2\].*Widen target_min",
        ),
        (
            {"target_min": (1.5, 1.5, 1.0), "target_max": (1.8, 1.8, 1.2)},
            "target region is empty",
        ),
    ],
)
def test_bad_regions_give_clear_errors(overrides, match):
    with pytest.raises(ValueError, match=match):
        mara_mjx.make(ORIENT, **overrides)


def test_bad_region_in_make_params():
    env = jitted(ORIENT).env
    with pytest.raises(ValueError, match="target_spread_deg"):
        env.make_params(target_spread_deg=181.0)
    with pytest.raises(ValueError, match="target region is empty"):
        env.make_params(target_min=(-0.5, -0.2, 0.1), target_max=(-0.3, 0.2, 0.3))


def test_evaluation_poses_are_held_out():
    env = jitted(ORIENT).env
    m, region = env.arm.mj_model, env.region
    a = targets.evaluation_poses(m, region, 200, seed=0)
    b = targets.evaluation_poses(m, region, 200, seed=0)
    c = targets.evaluation_poses(m, region, 200, seed=1)
    np.testing.assert_array_equal(a.pos, b.pos)  # reproducible
    assert len(np.unique(a.pos, axis=0)) == 200  # distinct
    assert np.all(region.contains(a.pos, a.quat))
    train = env.pose_table().pos
    gaps = np.linalg.norm(a.pos[:, None] - train[None], axis=-1).min(1)
    assert gaps.min() > 1e-6  # none is a training pose
    assert not np.any(np.all(np.isclose(a.pos[:, None], c.pos[None]), -1))  # seeds differ
    # the same integer seed in the two streams gives different poses
    same_seed = targets.candidates(m, region, 200, seed=0, stream=targets.TRAIN_STREAM)
    assert not np.any(np.all(np.isclose(a.pos[:, None], same_seed.pos[None]), -1))


def test_with_targets_fixes_each_episode_target():
    env = jitted(ORIENT).env
    poses = targets.evaluation_poses(env.arm.mj_model, env.region, 3, seed=0)
    params = with_targets(env.default_params, poses.pos, poses.quat)
    keys = jax.random.split(jax.random.key(0), 3)
    s = jax.jit(jax.vmap(env.reset))(keys, params)
    np.testing.assert_allclose(np.asarray(s.params.target_pos), poses.pos, atol=1e-6)
    np.testing.assert_allclose(np.asarray(s.metrics["target_quat"]), poses.quat, atol=1e-6)


def test_gym_env_target_moves_between_episodes():
    env = gymnasium.make(gym_id("MARARandomTarget"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Box(-inf, inf) / unnormalised actions
        check_env(env.unwrapped, skip_render_check=True)
    _, info0 = env.reset(seed=0)
    _, info1 = env.reset()
    assert set(info0) == set(METRIC_KEYS + TARGET_METRIC_KEYS)
    assert info0["target_pos"].shape == (3,)
    assert not np.array_equal(info0["target_pos"], info1["target_pos"])
    _, _, _, _, info = env.step(np.zeros(6, np.float32))
    np.testing.assert_array_equal(info["target_pos"], info1["target_pos"])
    env.close()


# ------------------------------------------------------------------ evaluation and play
@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A run folder with one MARACollisionOrientRandomTarget checkpoint of random
    weights (as tests/test_play.py: nothing compiles here)."""
    folder = tmp_path_factory.mktemp("random_target") / "run"
    env = jitted(ORIENT).env
    config = TrainConfig.of(hidden_sizes=(16, 16), relative_actions=True)
    network = make_network(config, env.action_size)
    obs = jax.ShapeDtypeStruct((env.observation_size,), jnp.float32)
    shapes = jax.eval_shape(network.init, jax.random.key(0), obs, obs)
    rng = np.random.default_rng(0)
    params = jax.tree.map(lambda x: 0.1 * rng.standard_normal(x.shape, np.float32), shapes)
    state = {"params": params, "obs_stats": RunningStats.create(env.observation_size)}
    meta = {
        "env_name": ORIENT,
        "env_config": env.config.to_dict(),
        "observation_size": env.observation_size,
        "action_size": env.action_size,
        **config.to_dict(),
        "run": {},
        "eval": {},
        "progress": {"update": 1, "env_steps": 1},
    }
    ckpt.save_checkpoint(folder / ckpt.CHECKPOINT_DIR / ckpt.checkpoint_name(1), state, meta)
    return folder


def _check_report(report_path: Path, episodes: int, driver: str) -> dict:
    report = json.loads(report_path.read_text())
    assert report["env_name"] == ORIENT and report["env_config"]["driver"] == driver
    s = report["summary"]
    assert s["poses"] == episodes and len(report["episodes"]) == episodes
    for group in ("position_error_mm", "orientation_error_deg"):
        for stat in ("mean", "median", "p95", "max"):
            assert len(s[group][stat]) == 3 and all(np.isfinite(s[group][stat]))
        assert s[group]["median"][0] <= s[group]["p95"][0] <= s[group]["max"][0]
    pos = np.array([e["position_error_mm"] for e in report["episodes"]])
    np.testing.assert_allclose(s["position_error_mm"]["mean"], pos.mean(0), rtol=1e-9)
    np.testing.assert_allclose(s["position_error_mm"]["max"], pos.max(0), rtol=1e-9)
    assert s["within_mm"]["5"] == pytest.approx(np.mean(np.all(pos <= 5, 1)))
    assert set(s["within_mm"]) == {"5", "1"} and set(s["within_deg"]) == {"5", "1"}
    assert s["collisions"] == sum(e["collisions"] for e in report["episodes"])
    region = targets.TargetRegion.from_config(mara_mjx.EnvConfig(**{
        k: tuple(v) if isinstance(v, list) else v
        for k, v in report["env_config"].items() if k.startswith("target_")
    }))  # fmt: skip
    tp = np.array([e["target_pos"] for e in report["episodes"]])
    tq = np.array([e["target_quat"] for e in report["episodes"]])
    assert np.all(region.contains(tp, tq)) and len(np.unique(tp, axis=0)) == episodes
    assert s["nearest_training_pose_mm"]["min"] > 0
    md = report_path.with_suffix(".md").read_text()
    assert "| 95th percentile |" in md and "| worst |" in md and "within 5 mm" in md
    png = report_path.with_suffix(".png")
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    return report


def test_evaluate_cli_on_a_random_target_run(run_dir, tmp_path):
    out = tmp_path / "eval" / "targets.json"
    args = [str(run_dir), "--episodes", "8", "--max_episode_steps", "4", "--json", str(out)]
    proc = subprocess.run(
        [sys.executable, "-m", "mara_mjx.evaluate", *args],
        cwd=REPO,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "8 held-out target poses" in proc.stdout and "| worst |" in proc.stdout
    report = _check_report(out, 8, "train")
    assert report["eval"]["tolerance_mm"] == 0.0  # run to the horizon by default
    assert all(e["steps"] == 4 for e in report["episodes"])


def test_evaluate_cli_refuses_rate_limit_on_the_train_driver(run_dir):
    """--rate_limit on a train-driver run without --driver real: a UserError naming the
    fix, before anything compiles."""
    from mara_mjx.cli import evaluate as evaluate_cli
    from mara_mjx.cli.common import UserError

    with pytest.raises(UserError, match="add --driver real, or drop --rate_limit"):
        evaluate_cli.main([str(run_dir), "--rate_limit", "true"])


def test_play_shows_each_episode_target(run_dir):
    from mara_mjx.cli import play
    from mara_mjx.ppo.config import EvalConfig

    task = RANDOM_TASKS[ORIENT]  # the marker is under test, not the physics
    env = _Counting(task, random_target_config(task).replace(max_episode_steps=1))
    policy = load_policy(run_dir)

    class Viewer:
        running = True
        shown: list = []

        def show(self, q, target_pos, target_quat):
            self.shown.append(np.array(target_pos))

    viewer = Viewer()
    config = EvalConfig(episodes=3, tolerance_mm=0.0)
    records = play.run_episodes(env, policy, config, viewer, None, None, hold=0.0)
    # the first pose while the policy compiles, then reset + 1 step per episode
    assert len(records) == 3 and len(viewer.shown) == 7
    np.testing.assert_array_equal(viewer.shown[0], viewer.shown[1])  # the same first target
    firsts = viewer.shown[1::2]
    assert len({tuple(t.round(6)) for t in firsts}) == 3  # the marker moved
    np.testing.assert_array_equal(viewer.shown[1], viewer.shown[2])  # fixed in an episode
    table = np.asarray(env.default_params.table_pos)
    assert all(np.any(np.all(table == t, axis=1)) for t in firsts)
