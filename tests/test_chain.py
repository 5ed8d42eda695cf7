"""The plain-jnp chain kinematics (mara_mjx.envs.chain) against MJX and C MuJoCo."""

from __future__ import annotations

import jax
import mujoco
import numpy as np

from mara_mjx.envs.arm import Arm
from mara_mjx.envs.chain import Chain


def test_chain_matches_mjx_and_c_mujoco():
    """TCP position, flange quaternion (w >= 0) and the geometric Jacobian of 200 random
    configurations inside the joint limits, to 1e-5."""
    arm = Arm()
    chain = Chain.from_model(arm.mj_model)
    qs = np.random.default_rng(0).uniform(arm.lower, arm.upper, size=(200, 6)).astype(np.float32)
    pose = jax.jit(jax.vmap(lambda q: arm.pose(q, collide=False)))(qs)
    tcp_pos, tcp_quat = jax.jit(jax.vmap(chain.tcp))(qs)
    jac = np.asarray(jax.jit(jax.vmap(chain.jacobian))(qs))
    np.testing.assert_allclose(tcp_pos, pose.tcp_pos, atol=1e-5)
    np.testing.assert_allclose(tcp_quat, pose.tcp_quat, atol=1e-5)
    np.testing.assert_allclose(jac[:, :3], pose.tcp_jac, atol=1e-5)
    m, d = arm.mj_model, mujoco.MjData(arm.mj_model)
    jac_pos, jac_rot = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for q, j in zip(qs[:50], jac[:50], strict=True):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jacSite(m, d, jac_pos, jac_rot, m.site("tcp").id)
        np.testing.assert_allclose(j[:3], jac_pos, atol=1e-5)
        np.testing.assert_allclose(j[3:], jac_rot, atol=1e-5)
