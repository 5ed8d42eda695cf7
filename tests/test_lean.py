"""The lean train-driver pass (mara_mjx/envs/lean.py) against MJX and C MuJoCo.

The full check (100,000 random and 100,000 near-contact configurations) is
benchmarks/lean_check.py; these are its small, fast counterparts."""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mara_mjx
from mara_mjx.envs.arm import Arm
from mara_mjx.envs.lean import segment_box_distance, segment_segment_distance

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from lean_check import c_mujoco, reference_flags  # noqa: E402


@pytest.fixture(scope="module")
def arm() -> Arm:
    return Arm()


def test_lean_pose_matches_mjx_and_flags_match_c_mujoco(arm):
    """2,000 random configurations inside the joint limits: TCP position, quaternion and
    Jacobian within 1e-5 of MJX; the collided flag equal to C MuJoCo's wherever C's
    smallest pair distance is beyond float32 precision (1e-6 m), except where an
    independent float64 reference finds a penetration that C MuJoCo's capsule-box test
    misses (the lean pass then agrees with the reference)."""
    qs = np.random.default_rng(1).uniform(arm.lower, arm.upper, (2000, 6)).astype(np.float32)
    mjx, lean = jax.jit(jax.vmap(arm.pose))(qs), jax.jit(jax.vmap(arm.lean.pose))(qs)
    for field in ("tcp_pos", "tcp_quat", "tcp_jac"):
        np.testing.assert_allclose(getattr(lean, field), getattr(mjx, field), atol=1e-5)
    c_flag, c_dist = c_mujoco(arm.mj_model, qs)
    lean_flag = np.asarray(lean.collided)
    assert 0.2 < c_flag.mean() < 0.8  # both kinds of configuration are tested
    disagree = np.where((lean_flag != c_flag) & (np.abs(c_dist) > 1e-6))[0]
    if len(disagree):
        ref = reference_flags(arm.lean, qs[disagree])
        np.testing.assert_array_equal(lean_flag[disagree], ref)
        assert np.all(ref & ~c_flag[disagree])  # only C's missed penetrations


def test_segment_distances_against_brute_force():
    """The closed forms against dense sampling on random segments and boxes, including
    parallel segments and segments through the box."""
    rng = np.random.default_rng(2)
    ts = np.linspace(0, 1, 2001)
    for i in range(200):
        p1, q1, p2 = rng.normal(size=(3, 3))
        q2 = p2 + (q1 - p1) * 0.7 if i % 10 == 0 else rng.normal(size=3)  # parallel cases
        seg_a = p1 + ts[:, None] * (q1 - p1)
        seg_b = p2 + ts[:, None] * (q2 - p2)
        brute = np.min(np.linalg.norm(seg_a[::10, None] - seg_b[None, ::10], axis=-1))
        fine = float(segment_segment_distance(*map(jnp.asarray, (p1, q1, p2, q2))))
        assert fine <= brute + 1e-6
        assert brute - fine < 2e-2  # the grid's resolution (every 10th of 2001 points)
        half = np.abs(rng.normal(size=3)) + 0.1
        a, b = rng.normal(size=(2, 3)) * 1.5
        pts = a + ts[:, None] * (b - a)
        want = np.sqrt(np.min(np.sum(np.maximum(np.abs(pts) - half, 0) ** 2, axis=1)))
        got = float(segment_box_distance(jnp.asarray(a), jnp.asarray(b), jnp.asarray(half)))
        assert abs(got - want) < 2e-3 and got <= want + 1e-6


def test_a_task_with_lean_kinematics_steps_like_mjx():
    """MARACollisionOrient with kinematics='lean' gives MJX's observations, rewards and
    collision counts over an episode of random actions (no configuration of which lies
    within 1e-4 m of contact by C MuJoCo)."""
    envs = {k: mara_mjx.make("MARACollisionOrient", kinematics=k) for k in ("mjx", "lean")}
    key = jax.random.key(3)
    lower, upper = envs["mjx"].joint_lower, envs["mjx"].joint_upper
    actions = np.random.default_rng(3).uniform(lower, upper, (40, 6)).astype(np.float32)
    _, c_dist = c_mujoco(envs["mjx"].arm.mj_model, actions)
    actions = actions[np.abs(c_dist) > 1e-4]

    def rollout(env):
        def body(state, a):
            state = env.step(state, a)
            return state, (state.obs, state.reward, state.metrics["collided"])

        return jax.lax.scan(body, env.reset(key), actions)[1]

    got = {k: jax.jit(rollout, static_argnums=0)(env) for k, env in envs.items()}
    for a, b in zip(got["mjx"], got["lean"], strict=True):
        np.testing.assert_allclose(a, b, atol=2e-5)
    assert 0 < float(np.sum(got["lean"][2])) < len(actions)  # collisions both ways


def test_lean_kinematics_config_errors():
    with pytest.raises(ValueError, match="kinematics='cuda' is not valid; choose one of"):
        mara_mjx.make("MARA", kinematics="cuda")
    # the real driver's collision checks use the pass unless MJX solves the contacts
    assert mara_mjx.make("MARA", driver="real").kinematics == "lean"
    assert mara_mjx.make("MARA", driver="real", real_contacts="physical").kinematics == "mjx"
