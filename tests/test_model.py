"""The MJCF model and the MJX arm against the spec and against C MuJoCo."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mara_mjx.envs import ik
from mara_mjx.envs.arm import XML_PATH, Arm, candidate_pairs, with_pairs
from mara_mjx.envs.base import DEFAULT_TARGET_POS, DEFAULT_TARGET_QUAT

TABLE_FOLD = np.array([0.0, 2.0, 0.0, 0.0, 0.0, 0.0])  # shoulder bent 115 deg: arm into the table
SELF_FOLD = np.array([0.0, 0.0, 2.2, 0.0, 2.5, 0.0])  # elbow + wrist folded: gripper into motor1
SPEC_REACH = np.array([1.3338, -1.5341, -0.7833, 0.0, 2.3903, -0.237])  # spec section 3


@pytest.fixture(scope="module")
def arm() -> Arm:
    return Arm()


@pytest.fixture(scope="module")
def pose_fn(arm):
    return jax.jit(jax.vmap(arm.pose))


def test_joint_table_and_limits(arm):
    m = arm.mj_model
    np.testing.assert_allclose(arm.lower, [-3.1416, -2.35, -2.61, -3.14, -2.56, -3.14])
    np.testing.assert_allclose(arm.upper, [3.1416, 2.35, 2.61, 3.14, 2.56, 3.14])
    axes = m.jnt_axis[arm.joint_ids]
    np.testing.assert_allclose(
        axes, [[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 0, 1], [-1, 0, 0], [0, 0, 1]]
    )
    np.testing.assert_allclose(m.jnt_actfrcrange[:, 1], [104, 104, 69, 69, 34, 34])
    np.testing.assert_allclose(m.body("motor3_link").mass, 3.95)


def test_tcp_at_zero_matches_spec(arm, pose_fn):
    pose = pose_fn(jnp.zeros((1, 6)))
    # spec section 2: with all joints at 0 the TCP is at about (-0.00105, 0, 1.7742)
    np.testing.assert_allclose(np.asarray(pose.tcp_pos[0]), [-0.00105369, 0.0, 1.77419], atol=1e-5)
    np.testing.assert_allclose(np.asarray(pose.tcp_quat[0]), [1, 0, 0, 0], atol=1e-6)
    assert not bool(pose.collided[0])


def test_mjx_kinematics_match_c_mujoco(arm, pose_fn):
    rng = np.random.default_rng(0)
    qs = rng.uniform(arm.lower, arm.upper, size=(16, 6))
    pose = pose_fn(jnp.asarray(qs, jnp.float32))
    m = arm.mj_model
    d = mujoco.MjData(m)
    jacp = np.zeros((3, 6))
    for i, q in enumerate(qs):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(pose.tcp_pos[i], d.site_xpos[arm.tcp_site], atol=2e-5)
        quat = d.xquat[arm.flange_body] * np.sign(d.xquat[arm.flange_body][0] or 1.0)
        np.testing.assert_allclose(pose.tcp_quat[i], quat, atol=2e-5)
        mujoco.mj_jacSite(m, d, jacp, None, arm.tcp_site)
        np.testing.assert_allclose(pose.tcp_jac[i], jacp, atol=2e-5)
        c_collided = bool(np.any(d.contact.dist[: d.ncon] < 0)) if d.ncon else False
        assert bool(pose.collided[i]) == c_collided


def test_spec_target_pose_is_reachable(arm):
    res = ik.solve(arm.mj_model, np.array(DEFAULT_TARGET_POS), np.array(DEFAULT_TARGET_QUAT))
    assert res.position_error < 1e-4  # 0.1 mm
    assert res.angle_error < 1e-3  # rad
    assert not res.collided
    assert np.all(res.q >= arm.lower) and np.all(res.q <= arm.upper)


def test_collision_detection_on_known_poses(arm, pose_fn):
    qs = jnp.asarray(np.stack([TABLE_FOLD, SELF_FOLD, np.zeros(6), SPEC_REACH]), jnp.float32)
    collided = np.asarray(pose_fn(qs).collided)
    assert collided.tolist() == [True, True, False, False]


def test_self_collision_is_robot_vs_robot(arm):
    m, d = arm.mj_model, mujoco.MjData(arm.mj_model)
    d.qpos[:] = SELF_FOLD
    mujoco.mj_kinematics(m, d)
    mujoco.mj_collision(m, d)
    pairs = {
        frozenset((m.geom(c.geom1).name, m.geom(c.geom2).name))
        for c in d.contact[: d.ncon]
        if c.dist < 0
    }
    assert pairs and all("table" not in p and "base" not in p for p in pairs)


def test_listed_pairs_flag_the_same_poses_as_all_spec_pairs(arm):
    """The pruned <contact> block loses no colliding configuration (fresh sample)."""
    m_list = arm.mj_model
    full = mujoco.MjModel.from_xml_string(with_pairs(XML_PATH.read_text(), candidate_pairs(m_list)))
    assert full.npair == 55 and m_list.npair < full.npair
    rng = np.random.default_rng(123)
    d1, d2 = mujoco.MjData(m_list), mujoco.MjData(full)
    for _ in range(3000):
        q = rng.uniform(arm.lower, arm.upper)
        flags = []
        for m, d in ((m_list, d1), (full, d2)):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_collision(m, d)
            flags.append(bool(np.any(d.contact.dist[: d.ncon] < 0)) if d.ncon else False)
        assert flags[0] == flags[1], q


def test_reset_region_is_collision_free(arm, pose_fn):
    """reset() skips collision detection: every pose within the largest reset_noise
    (0.5 rad) of zero must be collision-free."""
    rng = np.random.default_rng(7)
    qs = rng.uniform(-0.5, 0.5, size=(256, 6))
    qs[:64] = np.sign(qs[:64]) * 0.5  # corners of the box
    assert not np.any(np.asarray(pose_fn(jnp.asarray(qs, jnp.float32)).collided))


def test_unreachable_target_is_rejected(arm):
    with pytest.raises(ValueError, match="outside the arm's workspace"):
        ik.check_reachable(arm.mj_model, np.array([1.5, 0.0, 1.0]), None)
    with pytest.raises(ValueError, match="outside the arm's workspace"):
        ik.check_reachable(arm.mj_model, np.array([0.3, 0.0, 0.6]), None)  # inside the table
