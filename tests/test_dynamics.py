"""The plain-jnp physics step (mara_mjx/envs/dynamics.py) against `mjx.step`.

The same `mjx.Model` goes to both: the contact-free model of the 'detect' driver, and a
randomised copy of the friction model (envs/randomize.py). MJX's constraint solver
stops after the model's 4 iterations, converged or not; the reference here is MJX with
a converged solver (100 iterations), and MJX as shipped where no constraint acts.
"""

import contextlib
import copy
import io

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

with contextlib.redirect_stdout(io.StringIO()):  # "Failed to import warp"
    from mujoco import mjx

from mara_mjx.envs import randomize as rnd
from mara_mjx.envs.dynamics import Dynamics
from mara_mjx.envs.mara import _shared_arm

N = 512


def converged(arm):
    """The arm's contact-free MJX model with its solver run to convergence, and its data."""
    m = copy.deepcopy(arm.mj_model)
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    m.opt.iterations, m.opt.ls_iterations, m.opt.tolerance = 100, 50, 1e-15
    return mjx.put_model(m, impl="jax"), mjx.make_data(m, impl="jax")


def states(arm, seed, past=0.15):
    """N random states: q in the joint box with each joint past a limit by up to 0.02 rad
    with probability `past` (the limit rows act), qvel ~ N(0, 0.5) rad/s, servo
    references near q and reference velocities up to 1.57 rad/s."""
    rng = np.random.default_rng(seed)
    lo, hi = arm.lower, arm.upper
    q = rng.uniform(lo, hi, (N, 6))
    side = np.where(rng.uniform(size=(N, 6)) < 0.5, lo - rng.uniform(0, 0.02, (N, 6)),
                    hi + rng.uniform(0, 0.02, (N, 6)))  # fmt: skip
    q = np.where(rng.uniform(size=(N, 6)) < past, side, q)
    qvel = rng.normal(0, 0.5, (N, 6))
    ref = np.clip(q + rng.normal(0, 0.01, (N, 6)), lo, hi)
    ctrl = np.concatenate([ref, rng.uniform(-1.57, 1.57, (N, 6))], axis=1)
    return tuple(jnp.asarray(x, jnp.float32) for x in (q, qvel, ctrl))


def both(arm, model_fn, data, keys, q, qvel, ctrl):
    """(mjx.step's qpos, qvel), (Dynamics.step's q, qvel) on each state, (N, 6) each."""

    def one(key, q, qvel, ctrl):
        m = model_fn(key)
        d = mjx.step(m, data.replace(qpos=q, qvel=qvel, ctrl=ctrl))
        return (d.qpos, d.qvel), arm.dynamics.step(m, q, qvel, ctrl)

    return jax.tree.map(np.asarray, jax.jit(jax.vmap(one))(keys, q, qvel, ctrl))


def test_nominal_step_matches_mjx():
    """The nominal arm: within float32 rounding of converged MJX on every state (limits
    acting in about 60% of them), and of MJX as shipped where no limit acts."""
    arm = _shared_arm(False)
    model, data = converged(arm)
    keys = jax.random.split(jax.random.key(0), N)
    q, qvel, ctrl = states(arm, 0)
    (mq, mv), (lq, lv) = both(arm, lambda _: model, data, keys, q, qvel, ctrl)
    np.testing.assert_allclose(lq, mq, rtol=0, atol=1e-6)
    np.testing.assert_allclose(lv, mv, rtol=0, atol=1e-5)

    inside = np.all((np.asarray(q) > arm.lower) & (np.asarray(q) < arm.upper), axis=1)
    assert 0.2 < inside.mean() < 0.6
    shipped, data = arm.dynamics_model("detect"), arm._dynamics["detect"][1]
    (mq, mv), (lq, lv) = both(arm, lambda _: shipped, data, keys, q, qvel, ctrl)
    np.testing.assert_allclose(lv[inside], mv[inside], rtol=0, atol=1e-5)


def test_mass_matrix_and_smooth_forces_match_mjx():
    """M (with armature) and qfrc_smooth (servos, gravity compensation, bias forces)."""
    arm = _shared_arm(False)
    m, data = arm.dynamics_model("detect"), arm._dynamics["detect"][1]
    q, qvel, ctrl = states(arm, 1, past=0.0)

    def one(q, qvel, ctrl):
        d = mjx.forward(m, data.replace(qpos=q, qvel=qvel, ctrl=ctrl))
        mass, smooth, _ = arm.dynamics._smooth(m, q, qvel, ctrl)
        return (d._impl.M, d.qfrc_smooth), (mass, smooth)

    (m_ref, f_ref), (m_lean, f_lean) = jax.jit(jax.vmap(one))(q, qvel, ctrl)
    np.testing.assert_allclose(m_lean, m_ref, rtol=0, atol=1e-5 * np.abs(m_ref).max())
    np.testing.assert_allclose(f_lean, f_ref, rtol=0, atol=1e-5 * np.abs(f_ref).max())


def test_randomised_step_matches_mjx():
    """Per-env masses, inertias, damping, armature, gains and dry friction (the friction
    rows act in every state): converged MJX to 1e-6 rad in q, 5e-4 rad/s in qvel. The
    largest differences are MJX's: where they exceed 1e-5 rad/s, a float64 minimisation
    of the same constraint problem lands on this module's solution, not MJX's
    (measured: qacc 6e-5 from it against MJX's 5e-3 to 3e-2)."""
    arm = _shared_arm(True)
    model, data = converged(arm)
    randomizer = rnd.Randomizer(arm, rnd.RandomizeConfig())
    ranges = rnd.make_randomization(rnd.RandomizeConfig())
    keys = jax.random.split(jax.random.key(1), N)
    q, qvel, ctrl = states(arm, 2)
    (mq, mv), (lq, lv) = both(
        arm, lambda key: randomizer.model(model, rnd.draw(key, ranges)), data, keys, q, qvel, ctrl
    )
    np.testing.assert_allclose(lq, mq, rtol=0, atol=1e-6)
    np.testing.assert_allclose(lv, mv, rtol=0, atol=5e-4)
    assert np.mean(np.abs(lv - mv).max(axis=1) < 1e-5) > 0.99


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: setattr(m.opt, "integrator", mujoco.mjtIntegrator.mjINT_EULER),
        lambda m: m.jnt_stiffness.__setitem__(slice(None), 1.0),
    ],
)
def test_unsupported_models_are_refused(edit):
    m = copy.deepcopy(_shared_arm(False).mj_model)
    edit(m)
    with pytest.raises(ValueError, match="not a six-hinge chain of the form Dynamics writes out"):
        Dynamics.from_model(m)
