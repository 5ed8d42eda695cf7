"""PolicyConfig.plan_starts (mara_mjx.ppo.policy.restarted_landing): where the policy's own
plan misses the target, the plan is imagined again from fixed other postures and a landing
that reaches is commanded. Checked with an IK solver as the policy (a damped
least-squares step, which reaches from most postures): the own landing is kept where it
reaches, a restart's is taken only where it reaches, more targets end reached; the
options' bad values refused; the evaluation's and export's overrides (the ONNX trace of
a policy with a restart: tests/test_plan.py). A restart is taken only where the servos'
path to it keeps PLAN_CLEAR_MM from every contact, and of those the shortest; where none
reaches, the own landing's other wrist branch, solved by the IK step alone."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_export_plots import make_run

import mara_mjx
from mara_mjx.envs.clearance import clearance
from mara_mjx.envs.geometry import quat_conj, quat_mul
from mara_mjx.envs.task_space import joint_ranges, nominal_chain, pose_step, wrist_flip
from mara_mjx.ppo import PolicyConfig, make_policy, parametrisation
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import with_deployed
from mara_mjx.ppo.parametrisation import (
    PLAN_CLEAR_MM,
    PLAN_KEEP_MM,
    PLAN_PATH_POINTS,
    PLAN_START_STEPS,
)
from mara_mjx.ppo.policy import (
    _observation,
    _target,
    landing_error,
    path_clearance,
    planned_landing,
    restarted_landing,
    start_postures,
)

IK = {"ik_prior": "residual", "ik_gate": 0.1}


def ik(obs):
    """A policy that is an IK solver: one bounded damped-least-squares step to the target."""
    return obs[..., :6] + pose_step(obs[..., :6], obs[..., 6:9], obs[..., 9:13])


def pose_error(q, obs):
    """The largest of the position error per axis (mm) and the orientation error (deg) of
    the nominal TCP at joints q to the target that obs (at its own joints) reports."""
    tcp = jnp.vectorize(nominal_chain().tcp, signature="(6)->(3),(4)")
    p0, r0 = tcp(obs[..., :6])
    target_p, target_r = p0 - obs[..., 6:9], quat_mul(quat_conj(obs[..., 9:13]), r0)
    p, r = tcp(q)
    rot = quat_mul(r, quat_conj(target_r))
    deg = np.degrees(
        2 * np.arcsin(np.clip(np.linalg.norm(np.asarray(rot)[..., 1:], axis=-1), 0, 1))
    )
    return np.maximum(1000 * np.abs(np.asarray(p - target_p)).max(-1), deg)


def test_restarts_take_a_reaching_landing_only_where_the_own_one_misses():
    env = mara_mjx.make("MARAOrientRandomTarget")
    obs = jax.vmap(env.reset)(jax.random.split(jax.random.key(3), 48)).obs
    # 16 more: each at its own target (the own landing reaches there)
    at = obs[:16].at[:, 6:9].set(0.0).at[:, 9:13].set(jnp.array([1.0, 0, 0, 0]))
    both = jnp.concatenate([obs, at])
    own, got = (  # one compile: the own plan (one IK step: short of the target) and restarts
        np.asarray(x)
        for x in jax.jit(lambda o: (planned_landing(ik, o, 1), restarted_landing(ik, o, 1, 4)))(
            both
        )
    )
    np.testing.assert_array_equal(got[48:], own[48:])  # reached: kept, bit for bit
    own, got, obs = own[:48], got[:48], np.asarray(obs)
    own_err, got_err = pose_error(own, obs), pose_error(got, obs)
    assert (own_err > PLAN_KEEP_MM).all(), "one IK step from the reset pose should not reach"
    moved = np.abs(got - own).max(-1) > 0
    assert moved.sum() >= 24, "the restarts should reach most of these targets"
    assert (got_err[moved] <= PLAN_KEEP_MM + 1e-3).all()  # only a landing that reaches
    np.testing.assert_array_equal(got[~moved], own[~moved])  # else the own one
    np.testing.assert_array_equal(start_postures(8)[:4], start_postures(4))  # a fixed prefix


def test_the_servos_path_is_checked_not_only_its_ends():
    q0 = jnp.zeros(6)
    q1 = jnp.array([1.34, -0.65, 1.49, -2.51, 0.54, -1.0])  # both ends clear of contacts
    ends = np.asarray(clearance(jnp.stack([q0, q1])))
    line = jnp.linspace(0.0, 1.0, 65)[:, None] * q1  # the straight path: clear too
    got = jax.jit(path_clearance, static_argnums=2)(jnp.stack([q0, q0]), jnp.stack([q0, q1]), 64)
    assert (ends > 0.04).all() and float(jnp.min(clearance(line))) > 0.04
    # every joint at the same speed: the smaller moves end while joint 4 still turns, and
    # the arm passes through a contact on the way
    assert float(got[1]) < 0.0
    assert float(got[0]) == pytest.approx(float(ends[0]))  # not moving: where it stands


def test_restarts_take_the_shortest_clear_landing(monkeypatch):
    # a margin of 50 mm (2 by default): from the reset posture (82 mm clear) some reaching
    # restarts' paths come closer than that, and must be passed over
    monkeypatch.setattr(parametrisation, "PLAN_CLEAR_MM", 50.0)
    env = mara_mjx.make("MARAOrientRandomTarget")
    obs = jax.vmap(env.reset)(jax.random.split(jax.random.key(3), 48)).obs
    tcp = jnp.vectorize(nominal_chain().tcp, signature="(6)->(3),(4)")

    @jax.jit
    def landings(obs):  # every start's landing, its error and path clearance; the rule's choice
        q0 = obs[:, :6]
        tp, tq = _target(obs, q0, tcp)

        def one(s):
            q = jnp.broadcast_to(s, q0.shape)
            o = _observation(q, *tcp(q), 0 * tp, tp, tq, True)
            land = planned_landing(ik, o, PLAN_START_STEPS)
            path = path_clearance(q0, land, PLAN_PATH_POINTS)
            return land, landing_error(land, tp, tq, True), path

        lands, errs, paths = jax.lax.map(one, jnp.asarray(start_postures(4)))
        rule = restarted_landing(ik, obs, 1, 4)
        return lands, errs, paths, clearance(q0), planned_landing(ik, obs, 1), rule

    lands, errs, paths, here, own, got = (np.asarray(x) for x in landings(obs))
    reach, clear = errs <= PLAN_KEEP_MM, paths >= np.minimum(0.05, here)
    assert (reach & ~clear).sum() >= 5 and (reach & clear).sum() >= 24  # both kinds occur
    spans = np.abs(lands - np.asarray(obs)[:, :6]).max(-1)  # (4, 48): the largest joint move
    want_i = np.where(reach & clear, spans, np.inf).argmin(0)
    want = np.where((reach & clear).any(0)[:, None], lands[want_i, np.arange(48)], own)
    np.testing.assert_allclose(got, want, atol=1e-5)
    nearest = np.where(reach, errs, np.inf).argmin(0)  # the choice without the check
    assert ((reach & clear).any(0) & ~(reach & clear)[nearest, np.arange(48)]).any()


def test_bad_plan_starts_are_refused_with_the_valid_range():
    for bad in (-1, 33, 1.5):
        with pytest.raises(ValueError, match=r"plan_starts must be an int in \[0, 32\]"):
            PolicyConfig(plan_steps=4, plan_starts=bad, relative_actions=True)
    with pytest.raises(ValueError, match="needs plan_steps > 0"):
        PolicyConfig(plan_starts=4, relative_actions=True)
    for bad in (-2, 33):
        with pytest.raises(ValueError, match=r"plan_starts must be -1 \(as trained\) or in"):
            EvalConfig(plan_starts=bad)


def test_the_overrides_turn_restarts_on_and_off(tmp_path):
    from mara_mjx.cli.export import ExportError, export_policy
    from mara_mjx.ppo.evaluation import deployed_plan

    run = make_run(tmp_path / "run", "MARAOrient", True, relative=True, plan_steps=2,
                   plan_starts=2, constant_actor=True, **IK)  # fmt: skip
    policy = make_policy(run)
    assert policy.config.policy.plan_starts == 2
    obs = jax.vmap(mara_mjx.make("MARAOrient").reset)(jax.random.split(jax.random.key(0), 4)).obs
    base = with_deployed(policy, plan_steps=0, plan_starts=0)  # what the plan imagines
    got, want = jax.jit(lambda p, b, o: (p(o), restarted_landing(b, o, 2, 2)))(policy, base, obs)
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=1e-6)
    # the plan turned off takes its restarts with it, in the evaluation and the export
    off = deployed_plan(policy, EvalConfig(plan_steps=0)).config.policy
    assert (off.plan_steps, off.plan_starts) == (0, 0)
    assert deployed_plan(policy, EvalConfig(plan_starts=5)).config.policy.plan_starts == 5
    assert deployed_plan(policy, EvalConfig()) is policy  # as trained
    with pytest.raises(ValueError, match="needs plan_steps > 0"):
        deployed_plan(policy, EvalConfig(plan_steps=0, plan_starts=2))
    # (.npz refuses the IK prior: reached only once the plan's options were accepted)
    with pytest.raises(ExportError, match="ik_prior='residual'"):
        export_policy(run, tmp_path / "p.npz", plan_steps=0)
    with pytest.raises(ExportError, match="--plan_starts: .*needs plan_steps > 0"):
        export_policy(run, tmp_path / "p.npz", plan_steps=0, plan_starts=2)
    assert not (tmp_path / "p.npz").exists()


def test_the_other_wrist_branch_is_the_last_resort_where_joint_4_is_at_its_stop():
    # the pose of study 68's seed 1629, episode 18 (MARACollisionOrientRandomTarget): a
    # network that always lands at joint 4's stop (-3.14), 44 deg of yaw short; its
    # restarts land there too. The target is where the other wrist branch reaches it.
    chain = nominal_chain()
    lo, hi = (np.asarray(x) for x in joint_ranges())
    q = jnp.asarray(np.random.default_rng(5).uniform(0.7 * lo, 0.7 * hi, (64, 6)), jnp.float32)
    p0, r0 = jax.vmap(chain.tcp)(q)
    p1, r1 = jax.vmap(chain.tcp)(wrist_flip(q))
    assert float(jnp.max(jnp.linalg.norm(p1 - p0, axis=-1))) < 1.7e-3  # the wrist's offset
    assert float(jnp.max(jnp.abs(r1 - r0))) < 1e-5  # the tool's orientation: the same
    assert bool(jnp.all((wrist_flip(q) >= -np.pi) & (wrist_flip(q) <= np.pi)))
    stuck = jnp.array([1.64, 0.67, 2.12, -3.14, -1.32, 2.29])
    reach = jnp.array([[2.14, 0.33, 1.92, -0.41, 1.45, 0.43]])  # where seed 1616 lands
    tp, tq = jax.vmap(chain.tcp)(reach)
    here = jnp.zeros((1, 6))
    obs = _observation(here, *jax.vmap(chain.tcp)(here), jnp.zeros_like(tp), tp, tq, True)

    def pinned(o):
        return jnp.broadcast_to(stuck, o.shape[:-1] + (6,))

    got = jax.jit(lambda o: restarted_landing(pinned, o, 1, 4))(obs)
    assert float(landing_error(stuck[None], tp, tq, True)[0]) > 40.0  # the own landing misses
    assert float(landing_error(got, tp, tq, True)[0]) <= PLAN_KEEP_MM
    assert float(path_clearance(here, got, PLAN_PATH_POINTS)[0]) >= PLAN_CLEAR_MM / 1000.0
