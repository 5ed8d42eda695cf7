"""task_space.finish_step and PPOConfig.ik_finish, the MARA preset's IK finish (CPU, seconds).

Within ik_finish of the target position the saved policy's joint displacement is the
position-only IK step toward 1 cm short of the target, then onto it; the trainer's network
has no finish. The closed loops step the nominal chain's joints by the step (as the train
driver does) and stop, as the paper's evaluation does, at the first step with every axis
within 5 mm. Each jitted function is compiled once.
"""

from __future__ import annotations

import functools
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mara_mjx
from mara_mjx.envs.task_space import FINISH_HOLD, finish_step, nominal_chain, pose_step
from mara_mjx.ppo.config import TrainConfig, for_env
from mara_mjx.ppo.networks import forward, make_network
from mara_mjx.ppo.presets import PRESETS, default_preset

POSTURE = np.array([0.4, -0.5, 0.9, 0.1, 1.2, 0.0])
"""A well-conditioned posture of the arm (rad), as in tests/test_ik_orient_first.py."""
TOLERANCE = 0.005
"""m per axis: the paper's evaluation stops at the first step within it."""


def _starts() -> tuple[np.ndarray, np.ndarray]:
    """(targets (N, 3), start postures (N, 6)): from POSTURE's TCP, targets 3-5.9 cm away
    along 12 directions (the world axes, both signs, and 6 skewed ones)."""
    rng = np.random.default_rng(0)
    dirs = np.concatenate([np.eye(3), -np.eye(3), rng.normal(size=(6, 3))])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dist = np.linspace(0.03, 0.059, len(dirs))[:, None]
    tcp = np.asarray(nominal_chain().tcp(jnp.asarray(POSTURE, jnp.float32))[0])
    return tcp + dirs * dist, np.tile(POSTURE, (len(dirs), 1))


@functools.cache
def _entries() -> dict[str, np.ndarray]:
    """|e| per axis (N, 3) at the first step within TOLERANCE, for the finish and for the
    plain IK step (onto the target from the start), and the finish's error after 40 steps."""
    targets, q0 = (jnp.asarray(x, jnp.float32) for x in _starts())
    chain = nominal_chain()

    def error(q, target):
        return chain.tcp(q)[0] - target

    def loop(step):
        def one(q, target):
            def body(carry, _):
                q, entry, inside = carry
                e = error(q, target)
                now = jnp.all(jnp.abs(e) < TOLERANCE)
                entry = jnp.where(now & ~inside, jnp.abs(e), entry)
                return (q + step(q, e), entry, inside | now), None

            init = (q, jnp.full(3, jnp.inf), jnp.zeros((), bool))
            (q, entry, _), _ = jax.lax.scan(body, init, None, length=40)
            return entry, jnp.abs(error(q, target))

        return jax.jit(jax.vmap(one))(q0, targets)

    finish, held = loop(finish_step)
    plain, _ = loop(lambda q, e: pose_step(q, e))
    return {"finish": np.asarray(finish), "plain": np.asarray(plain), "held": np.asarray(held)}


def test_finish_enters_the_tolerance_within_a_fraction_of_a_millimetre():
    """From 3-6 cm away the finish's first step inside the 5 mm box is a Newton step from
    about 1 cm: under 0.2 mm on every axis, and it then holds the target (< 1 um); the
    plain IK step, one 5-cm Newton step, enters millimetres off on some of the same starts
    (the check has teeth)."""
    got = _entries()
    assert np.isfinite(got["finish"]).all(), got["finish"]  # every start entered
    assert got["finish"].max() < 2e-4, got["finish"]
    assert got["held"].max() < 1e-6, got["held"]
    assert got["plain"].max() > 5 * got["finish"].max(), got["plain"]


def test_finish_step_aims_short_of_the_target_until_within_the_hold():
    """Farther than 1.2 cm: the step is the plain IK step toward the point 1 cm short of
    the target on the line to it; within: the plain step onto the target."""
    q = jnp.asarray(POSTURE, jnp.float32)
    far = jnp.asarray([0.03, -0.02, 0.01], jnp.float32)
    aim = far * (1.0 - FINISH_HOLD / jnp.linalg.norm(far))
    np.testing.assert_allclose(finish_step(q, far), pose_step(q, aim), atol=1e-6)
    near = far * (1.1 * FINISH_HOLD / jnp.linalg.norm(far))
    np.testing.assert_allclose(finish_step(q, near), pose_step(q, near), atol=1e-6)


@pytest.fixture(scope="module")
def mara():
    return mara_mjx.make("MARA")


def test_ik_finish_is_deployed_only_and_replaces_the_step_near_the_target(mara):
    """The saved policy's mean is q + finish_step(q, e) within ik_finish of the target and
    the learnt mean elsewhere (the same as without the finish); the trainer's network has
    no finish."""
    config = for_env(PRESETS["ik_finish"], mara)
    assert config.policy.ik_finish == 0.06
    saved, trainer = make_network(config, 6), make_network(config, 6, training=True)
    assert saved.ik_finish == 0.06 and trainer.ik_finish == 0.0
    assert trainer == make_network(config.replace(ik_finish=0.0), 6)
    obs = jnp.asarray(np.random.default_rng(1).normal(0.0, 0.5, (8, mara.observation_size)))
    scale = jnp.asarray([0.5, 0.05, 0.5, 0.05, 0.3, 0.02, 1.0, 0.001])  # |e| near and far
    obs = obs.at[:, 6:9].multiply(scale[:, None])
    params = trainer.init(jax.random.PRNGKey(0), obs, obs)
    params = jax.tree_util.tree_map(lambda x: x + 0.1, params)  # a learnt, non-zero actor
    mean, *_ = forward(saved, params, None, obs, 10.0)
    learnt, *_ = forward(trainer, params, None, obs, 10.0)
    near = np.linalg.norm(np.asarray(obs[:, 6:9]), axis=1) < 0.06
    assert near.any() and (~near).any()
    finish = obs[:, :6] + finish_step(obs[:, :6], obs[:, 6:9])
    np.testing.assert_allclose(mean[near], finish[near], atol=1e-6)
    np.testing.assert_array_equal(mean[~near], learnt[~near])
    assert np.abs(np.asarray(learnt - finish))[near].max() > 1e-3  # they differ there


def test_ik_finish_is_validated_and_refused_on_an_orientation_task(mara):
    """Bad values, a missing relative_actions and an Orient task are clear errors that
    name the way out; the train CLI trains MARA with it (ppo.presets.default_preset)."""
    with pytest.raises(ValueError, match="ik_finish"):
        TrainConfig.of(ik_finish=-0.1, relative_actions=True)
    with pytest.raises(ValueError, match="relative_actions=true"):
        TrainConfig.of(ik_finish=0.06)
    with pytest.raises(ValueError, match="--preset orient_first"):
        for_env(PRESETS["ik_finish"], mara_mjx.make("MARAOrient"))
    assert for_env(PRESETS["ik_finish"], mara_mjx.make("MARACollision")).policy.ik_finish == 0.06
    assert default_preset("MARA") == "ik_finish"
    assert PRESETS["ik_finish"] == PRESETS["default"].replace(ik_finish=0.06)


def test_hidden_obs_past_the_observation_is_a_clear_error(mara):
    """hidden_obs names observation entries; one past the env's observation (MARAOrient's
    13-15 on MARA) was silently ignored by JAX's scatter and crashed the export: for_env
    now names the problem and the valid range."""
    with pytest.raises(ValueError, match="0-11"):
        for_env(TrainConfig.of(hidden_obs=(13, 14, 15)), mara)
    assert for_env(TrainConfig.of(hidden_obs=(9, 10, 11)), mara).policy.hidden_obs == (9, 10, 11)


def test_ik_inputs_passed_in_give_the_forward_pass_the_network_computes():
    """The trainer computes the IK step once per rollout sample (networks.ik_inputs) and
    passes it to the later forward passes (values, each epoch's minibatches): the same
    mean and value as the network computing it, trainer's and saved networks alike."""
    from mara_mjx.ppo.networks import ik_inputs

    env = mara_mjx.make("MARAOrient")
    config = for_env(PRESETS["orient_first"], env)
    obs = jnp.asarray(np.random.default_rng(3).normal(0.0, 0.5, (16, env.observation_size)))
    for training in (True, False):
        network = make_network(config, 6, training=training)
        params = network.init(jax.random.PRNGKey(1), obs, obs)
        params = jax.tree_util.tree_map(lambda x: x + 0.05, params)
        ik = ik_inputs(network, obs)
        assert ik is not None and ik[0].shape == (16, 6)
        got = forward(network, params, None, obs, 10.0, ik)
        want = forward(network, params, None, obs, 10.0)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)
    assert ik_inputs(make_network(PRESETS["default"], 6), obs) is None


def test_stop_outside_shortens_a_jump_into_the_zone_to_just_inside_its_edge():
    """A joint step taking the TCP from 10 cm to the target is cut to the crossing of the
    6-cm sphere (the TCP lands just inside it); a step that stays outside, and one from
    inside, are unchanged."""
    from mara_mjx.envs.task_space import stop_outside

    chain = nominal_chain()
    q = jnp.asarray(POSTURE, jnp.float32)
    goal = q + jnp.asarray([0.15, -0.1, 0.1, 0.0, 0.1, 0.0])  # the target's posture
    target = chain.tcp(goal)[0]
    e = chain.tcp(q)[0] - target
    assert 0.08 < float(jnp.linalg.norm(e)) < 0.3, e
    radius = 0.5 * float(jnp.linalg.norm(e))
    cut = stop_outside(q, e, goal - q, radius)
    ratio = np.asarray(cut / (goal - q))[[0, 1, 2, 4]]
    assert np.ptp(ratio) < 1e-6 and 0.0 < ratio[0] < 1.0  # the same step, shortened
    after = float(jnp.linalg.norm(chain.tcp(q + cut)[0] - target))
    assert radius - 1e-3 < after < radius, (after, radius)
    small = 0.1 * (goal - q)  # stays outside the zone
    np.testing.assert_array_equal(stop_outside(q, e, small, radius), small)
    inside = stop_outside(q, e, goal - q, 2.0 * float(jnp.linalg.norm(e)))  # already in
    np.testing.assert_array_equal(inside, goal - q)


def test_stop_outside_batched_and_differentiable_through_the_step():
    """A batch mixing jumps into the zone with steps that stay out or start in: only the
    jumps are shortened; the result is alpha x the step with alpha held fixed, so the
    actor's gradient flows through the step (a guard in a trainer's network must not cut
    it)."""
    from mara_mjx.envs.task_space import stop_outside

    chain = nominal_chain()
    q = jnp.asarray(np.tile(POSTURE, (3, 1)), jnp.float32)
    goal = q[0] + jnp.asarray([0.15, -0.1, 0.1, 0.0, 0.1, 0.0])
    target = chain.tcp(goal)[0]
    e = jax.vmap(lambda q1: chain.tcp(q1)[0] - target)(q)
    radius = 0.5 * float(jnp.linalg.norm(e[0]))
    dq = jnp.stack([goal - q[0], 0.1 * (goal - q[1]), goal - q[2]])
    e = e.at[2].set(0.1 * e[2])  # the third starts inside the zone
    cut = stop_outside(q, e, dq, radius)
    assert float(jnp.max(jnp.abs(cut[0] - dq[0]))) > 1e-3  # the jump: shortened
    np.testing.assert_array_equal(cut[1:], dq[1:])  # the others: unchanged
    grad = jax.grad(lambda d: jnp.sum(stop_outside(q, e, d, radius)))(dq)
    assert np.all(np.asarray(grad[1:]) == 1.0) and 0.0 < float(grad[0, 0]) < 1.0


def test_the_orient_first_guard_is_deployed_only_and_keeps_the_actor_trainable():
    """The saved orient_first network shortens a learnt step that jumps into the 6-cm zone
    (its TCP lands just inside the edge); the trainer's network has no guard, with the
    loose rule or without it, and the actor's gradient is non-zero in both."""
    from mara_mjx.envs.task_space import ORIENT_FIRST_NEAR

    env = mara_mjx.make("MARAOrient")
    # the zone's guard alone: the preset's collision guard would also shorten this jump,
    # whose landing posture is near a contact (tests/test_clearance.py tests that guard)
    config = for_env(PRESETS["orient_first"].replace(collision_guard_mm=0.0), env)
    chain = nominal_chain()
    q = jnp.asarray(POSTURE, jnp.float32)
    far = chain.tcp(q + jnp.asarray([0.3, -0.2, 0.2, 0.0, 0.2, 0.0]))[0]
    obs = jnp.zeros(env.observation_size).at[:6].set(q).at[6:9].set(chain.tcp(q)[0] - far)
    obs = obs.at[9].set(1.0)  # quat_err (w, x, y, z): aligned
    saved = make_network(config, 6)
    params = saved.init(jax.random.PRNGKey(0), obs, obs)
    # a learnt correction that jumps: the actor's output (its last layer's bias, the
    # kernel zero) is the step onto the target's posture less the IK step, over the gate
    from mara_mjx.ppo.networks import ik_gate, ik_inputs

    step = jnp.asarray([0.3, -0.2, 0.2, 0.0, 0.2, 0.0])
    last = params["params"]["actor"]["Dense_2"]
    last["kernel"] = jnp.zeros_like(last["kernel"])
    last["bias"] = (step - ik_inputs(saved, obs)[0]) / ik_gate(obs, config.policy.ik_gate)
    unguarded = make_network(config, 6).clone(ik_guard=False)
    jump, *_ = forward(unguarded, params, None, obs, 10.0)
    assert float(jnp.linalg.norm(chain.tcp(jump)[0] - far)) < 1e-3  # it would land on it
    mean, *_ = forward(saved, params, None, obs, 10.0)
    e_after = chain.tcp(mean)[0] - far
    assert saved.ik_guard
    assert float(jnp.linalg.norm(obs[6:9])) > ORIENT_FIRST_NEAR
    assert 0.05 < float(jnp.linalg.norm(e_after)) < ORIENT_FIRST_NEAR, e_after
    for loose in (True, False):
        trainer = make_network(config.replace(train_ik_orient_loose=loose), 6, training=True)
        assert not trainer.ik_guard

        def loss(p, trainer=trainer):
            return jnp.sum(forward(trainer, p, None, obs, 10.0)[0])

        grad = jax.grad(loss)(params)["params"]["actor"]
        assert sum(float(jnp.abs(g).sum()) for g in jax.tree.leaves(grad)) > 0.0, loose


def test_one_update_with_the_stored_ik_step_matches_computing_it_in_every_pass(monkeypatch):
    """The trainer stores each sample's IK step (ppo.train's ik_inputs) and passes it to
    the value passes and the minibatches; computing it in every forward pass instead (the
    stored value patched out) gives the same update (float tolerance: XLA may fuse the two
    programs differently)."""
    import mara_mjx.ppo.train as ppo_train
    from mara_mjx.ppo import make_train

    env = mara_mjx.make("MARAOrient")
    config = PRESETS["orient_first"].replace(
        num_envs=8, num_steps=4, num_minibatches=2, update_epochs=2, total_timesteps=8 * 4 * 2,
        probe_reach_steps=0,  # the preset's probe of the saved policy is not under test
    )  # fmt: skip

    def one_update():
        trainer = make_train(env, config, updates_per_call=1, devices=1)
        init = trainer.init(jax.random.key(0))
        start = jax.tree.leaves(jax.device_get(init.params))
        state, _ = trainer.run(init, 1)
        return jax.tree.leaves(jax.device_get(state.params)), start

    stored, start = one_update()
    monkeypatch.setattr(ppo_train, "ik_inputs", lambda network, obs: None)
    computed, _ = one_update()
    moved = max(float(np.abs(a - b).max()) for a, b in zip(stored, computed, strict=True))
    assert moved < 1e-5, moved
    assert max(float(np.abs(a - b).max()) for a, b in zip(stored, start, strict=True)) > 1e-4


def batched_lapack_calls(stablehlo: str) -> list[str]:
    """The LAPACK custom calls of a lowered program whose first operand has a batch
    dimension (rank > 2): the ones jaxlib splits over XLA's CPU thread pool."""
    found = []
    for line in stablehlo.splitlines():
        if "custom_call" in line and "lapack_" in line:
            operand = re.search(r":\s*\(tensor<([^>]*)>", line)
            if operand and operand.group(1).count("x") > 2:
                found.append(line.strip()[:160])
    return found


def test_cpu_training_programs_hold_no_batched_lapack_call_and_the_ik_solve_is_exact():
    """jaxlib's batched LAPACK LU on a CPU blocks XLA's intra-op pool threads while its
    parts run on the same pool: two at once on a 2-core machine and the program never
    finishes (the train CLI's Orient default hung at its first update; NOTES section 30).
    On a CPU the IK step's solve is written out (envs/linalg.py) and --seeds initialises
    the seeds one after another (the orthogonal init's QR, vmapped, is a batched LAPACK
    call too): the Orient default's --seeds programs hold no LAPACK call, and the solve
    matches float64's."""
    from mara_mjx.envs.task_space import dls_step
    from mara_mjx.ppo import make_train
    from mara_mjx.ppo.members import make_seed_trainer

    assert jax.default_backend() == "cpu"
    env = mara_mjx.make("MARACollisionOrient")
    config = PRESETS[default_preset("MARACollisionOrient")].replace(
        num_envs=8, num_steps=4, num_minibatches=2, update_epochs=1, total_timesteps=8 * 4
    )
    assert config.policy.ik_prior  # the IK step is in this program
    trainer = make_train(env, config, updates_per_call=1, devices=1)
    seeds = make_seed_trainer(trainer, (0, 1), devices=1)  # vmapped: a batched QR at init
    state = jax.eval_shape(seeds.init)
    texts = [seeds.init.trace().lower().as_text(), seeds.run.trace(state, 1).lower().as_text()]
    assert [batched_lapack_calls(text) for text in texts] == [[], []]
    batched = jax.jit(jax.vmap(jnp.linalg.solve)).lower(jnp.ones((4, 6, 6)), jnp.ones((4, 6)))
    assert batched_lapack_calls(batched.as_text())  # the check finds one

    rng = np.random.default_rng(0)
    chain = nominal_chain()
    for _ in range(20):
        q = rng.uniform(-2.0, 2.0, 6)
        full = np.asarray(chain.jacobian(jnp.asarray(q, jnp.float32)), np.float64)
        cases = [(full, 6), (full[:3], 3), (full[:, :5], 6)]  # as task_space's calls
        for jac, dx in ((jac, rng.normal(size=m) * 0.05) for jac, m in cases):
            got = np.asarray(dls_step(jnp.asarray(jac, jnp.float32), jnp.asarray(dx, jnp.float32)))
            want = jac.T @ np.linalg.solve(jac @ jac.T + 0.02**2 * np.eye(len(dx)), dx)
            assert np.abs(got - want).max() <= 2e-3 * np.abs(want).max() + 1e-7


PINNED = np.array(
    [
        [0.5271, -2.35, -1.5879, -1.7551, -2.1176, 3.14],
        [0.4515, -2.35, -1.4499, -1.7228, -2.2976, 3.0086],
        [0.4115, -2.2893, -1.4734, -1.6955, -2.2892, 3.14],
        [0.4673, -2.3434, -1.7359, -1.9791, -2.3329, 3.14],
        [0.362, -2.35, -1.4409, -1.8868, -2.2296, 2.9898],
        [0.5162, -2.2887, -1.6465, -1.7663, -2.1976, 3.14],
    ],
    np.float32,
)
"""Postures on the edge of the 6-cm finish zone around MARA's target, the shoulder (joint 2)
at or near its -2.35 rad stop, as some seeds' policies approach (benchmarks/NOTES.md
section 52, from a sweep of 3,000 such starts)."""


def test_finish_respects_the_joint_limits_where_a_joint_is_at_its_stop(mara):
    """The env clips joint targets to the limits. From PINNED, stepping the nominal chain
    and clipping as the env does, the finish (task_space.limited_step: the joints the step
    would take past a stop held there, the others solved again) enters the paper's 5 mm
    box under 0.3 mm on every axis; the same aims with the step that ignores the limits
    (pose_step) enter 1.6-4.9 mm off. An exported file's numpy finish takes the same step."""
    from mara_mjx.deploy.ik_numpy import NumpyFinish, finish_meta
    from mara_mjx.envs.task_space import FINISH_WITHIN, joint_ranges

    target = np.asarray(mara.config.target_pos, np.float32)
    lo, hi = (np.asarray(x, np.float32) for x in joint_ranges())
    chain = nominal_chain()
    tcp = jax.jit(jax.vmap(lambda q: chain.tcp(q)[0]))

    def aim(e):
        dist = jnp.linalg.norm(e, axis=-1, keepdims=True)
        short = e * (1.0 - FINISH_HOLD / dist)
        return jnp.where(dist > FINISH_WITHIN * FINISH_HOLD, short, e)

    def entry(step):
        q, got = PINNED.copy(), np.full((len(PINNED), 3), np.nan)
        for _ in range(12):
            e = np.asarray(tcp(q)) - target
            new = np.isnan(got[:, 0]) & np.all(np.abs(e) < TOLERANCE, axis=1)
            got[new] = np.abs(e[new])
            q = np.clip(q + np.asarray(step(q, e)), lo, hi)
        return got

    e0 = np.asarray(tcp(PINNED)) - target
    assert np.allclose(np.linalg.norm(e0, axis=1), 0.0599, atol=1e-4)  # on the zone's edge
    limited = entry(jax.jit(finish_step))
    plain = entry(jax.jit(lambda q, e: pose_step(q, aim(e))))
    assert np.isfinite(limited).all() and limited.max() < 3e-4, limited
    assert (plain.max(axis=1) > 1.5e-3).all(), plain  # the check has teeth
    numpy_step = NumpyFinish(finish_meta(0.06)).finish_step(PINNED.astype(np.float64), e0)
    np.testing.assert_allclose(numpy_step, np.asarray(finish_step(PINNED, e0)), atol=2e-5)
    old = NumpyFinish({**finish_meta(0.06), "limited": False})  # a file exported before
    np.testing.assert_allclose(
        old.finish_step(PINNED.astype(np.float64), e0),
        np.asarray(pose_step(PINNED, aim(e0))),
        atol=2e-5,
    )
