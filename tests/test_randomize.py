"""Domain randomisation (mara_mjx/envs/randomize.py): draws inside their ranges and
different per env, randomisation off is the plain env, latency delays by exactly k steps,
calibration offsets act in the encoders' frame, bad ranges are clear errors.

One randomised MARA env (train driver, buffer for up to 3 steps of latency) is compiled
once; every case below changes only its params (traced), so nothing recompiles."""

import dataclasses

import jax
import numpy as np
import pytest
from conftest import jitted

import mara_mjx
from mara_mjx.envs import randomize as rnd
from mara_mjx.envs.randomize import RandomizeConfig
from mara_mjx.runtime import runs

OFF = RandomizeConfig.off()
MAX_LATENCY = 3


@pytest.fixture(scope="module")
def randomized():
    return jitted("MARA", randomize=True, randomization=OFF.replace(latency_steps=(0, MAX_LATENCY)))


def test_draws_stay_in_their_ranges_and_differ_across_envs():
    cfg = RandomizeConfig(latency_steps=(0, 3), calibration_offset=0.004)
    r = rnd.make_randomization(cfg)
    draws = jax.vmap(rnd.draw, in_axes=(0, None))(jax.random.split(jax.random.key(3), 64), r)
    d = jax.tree.map(np.asarray, draws.draw)
    for name in rnd.RANGE_FIELDS:
        low, high = getattr(cfg, name)
        assert d[name].shape == (64, 6)
        assert np.all((d[name] >= low) & (d[name] <= high)), name
        assert np.unique(d[name][:, 0]).size == 64, f"{name} is the same in several envs"
    assert np.all(np.abs(d["offset"]) <= 0.004) and np.unique(d["offset"][:, 0]).size == 64
    assert set(np.unique(d["latency"])) == {0, 1, 2, 3}


def test_random_target_reset_draws_both_target_and_physics():
    env = mara_mjx.make("MARARandomTarget", randomize=True, target_table_size=16)
    keys = jax.random.split(jax.random.key(0), 8)
    s = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, env.default_params)
    assert np.unique(np.asarray(s.params.randomization.draw["kp_scale"][:, 0])).size == 8
    assert np.unique(np.asarray(s.params.target_pos[:, 0])).size > 1
    # the policy sees the encoders: q + offset + noise (reset pose: q = 0)
    seen = np.asarray(s.obs[:, :6]) - np.asarray(s.params.randomization.draw["offset"])
    assert np.all(np.abs(seen) < 6 * RandomizeConfig().obs_noise_std) and np.any(seen != 0)


def test_default_env_has_no_randomisation_in_its_state(mara):
    s = mara.reset(jax.random.key(0))  # as the other tests call it: no retrace
    assert s.params.randomization is None and s.action_history is None
    assert mara.env.randomizer is None


def _rollout(j, params, actions, key=1):
    s = j.reset(jax.random.key(key)) if params is None else j.reset(jax.random.key(key), params)
    out = []
    for a in actions:
        s = j.step(s, a)
        out.append(s)
    return s, out


ACTIONS = np.array(
    [[0.1 * (i + 1), -0.2 + 0.05 * i, 0.3, -0.1 * i, 0.2, 0.05 * i] for i in range(6)], np.float32
)


def test_randomisation_at_nominal_values_is_the_plain_env(mara, randomized):
    params = randomized.env.make_params(randomization=OFF)
    _, plain = _rollout(mara, None, ACTIONS)
    _, rand = _rollout(randomized, params, ACTIONS)
    for p, r in zip(plain, rand, strict=True):
        np.testing.assert_array_equal(p.obs, r.obs)
        np.testing.assert_array_equal(p.reward, r.reward)
        np.testing.assert_array_equal(p.q, r.q)
        for k in p.metrics:
            np.testing.assert_array_equal(p.metrics[k], r.metrics[k], err_msg=k)


@pytest.mark.parametrize("k", [0, 1, 3])
def test_latency_of_k_steps_delays_the_applied_action_by_exactly_k(randomized, k):
    params = randomized.env.make_params(randomization=OFF.replace(latency_steps=(k, k)))
    _, states = _rollout(randomized, params, ACTIONS)
    for t, s in enumerate(states):
        # the train driver teleports: q after step t is the command applied at step t
        expected = ACTIONS[t - k] if t >= k else np.zeros(6)  # the reset pose is held
        np.testing.assert_allclose(s.q, expected, atol=1e-7, err_msg=f"step {t}")


def test_calibration_offset_acts_in_the_encoders_frame(randomized):
    params = randomized.env.make_params(randomization=OFF.replace(calibration_offset=0.01))
    s, states = _rollout(randomized, params, ACTIONS[:2])
    offset = np.asarray(s.params.randomization.draw["offset"])
    assert np.all(np.abs(offset) <= 0.01) and np.all(offset != 0)
    # the servo puts the encoder reading (q + offset) at the command: the true q is off
    np.testing.assert_allclose(s.q, ACTIONS[1] - offset, atol=1e-6)
    np.testing.assert_allclose(s.obs[:6], ACTIONS[1], atol=1e-6)
    # e is the forward kinematics of the measured joints; the metrics are the true error
    true_e = np.asarray(s.metrics["position_error"])
    assert not np.allclose(np.abs(s.obs[6:9]), true_e, atol=1e-5)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("mass_scale", (1.2, 0.8), "mass_scale=[1.2, 0.8]: low must be <= high"),
        ("kp_scale", (0.0, 1.0), "kp_scale=[0.0, 1.0]: a scale must be > 0"),
        ("damping", (-1.0, 1.0), "damping=[-1.0, 1.0] must be >= 0"),
        ("frictionloss", (0.0, float("nan")), "frictionloss must be two finite numbers"),
        ("inertia_scale", (1.0,), "inertia_scale must be two finite numbers"),
        ("calibration_offset", -0.1, "calibration_offset=-0.1 must be in [0, 0.2] rad"),
        ("obs_noise_std", "x", "obs_noise_std='x' must be in [0, 0.2] rad"),
        ("latency_steps", (2, 1), "latency_steps=(2, 1) must be two ints"),
        ("latency_steps", (0, 99), "latency_steps=(0, 99) must be two ints"),
    ],
)
def test_bad_ranges_are_clear_errors(field, value, message):
    with pytest.raises(ValueError, match="randomization." + _escape(message)):
        RandomizeConfig(**{field: value})


def _escape(text: str) -> str:
    import re

    return re.escape(text)


def test_env_level_errors(randomized):
    with pytest.raises(ValueError, match="randomize=1 must be true or false"):
        mara_mjx.make("MARA", randomize=1)
    with pytest.raises(ValueError, match="exceeds the action buffer"):
        randomized.env.make_params(randomization=OFF.replace(latency_steps=(0, 4)))
    with pytest.raises(ValueError, match="need an env built with randomize=True"):
        mara_mjx.make("MARA").make_params(randomization=OFF)
    with pytest.raises(ValueError, match="randomize is fixed when the env is built"):
        randomized.env.make_params(randomize=False)
    # a partial dict (the CLI's flags, a saved config) applies on top of the env's ranges
    cfg = randomized.env.config.replace(randomization={"kp_scale": [0.5, 0.6]})
    assert cfg.randomization.kp_scale == (0.5, 0.6)
    assert cfg.randomization.latency_steps == (0, MAX_LATENCY)
    again = mara_mjx.EnvConfig().replace(**runs.env_overrides(cfg.to_dict()))
    assert dataclasses.asdict(again.randomization) == dataclasses.asdict(cfg.randomization)


def test_flags_apply_on_top_of_a_checkpoints_ranges():
    saved = mara_mjx.EnvConfig(randomize=True, randomization=RandomizeConfig(kp_scale=(0.5, 0.6)))
    meta = {"env_name": "MARA", "env_config": saved.to_dict(), "observation_size": 12}
    env = runs.make_env(meta, randomization={"latency_steps": (0, 2)})
    assert env.config.randomize and env.randomizer.buffer_size == 3
    assert env.config.randomization.kp_scale == (0.5, 0.6)
    assert env.config.randomization.latency_steps == (0, 2)


def test_physics_draw_reaches_the_mjx_model():
    from mara_mjx.envs.mara import _shared_arm

    arm = _shared_arm(frictionloss=True)
    randomizer = rnd.Randomizer(arm, RandomizeConfig())
    r = rnd.draw(jax.random.key(5), rnd.make_randomization(RandomizeConfig()))
    d = jax.tree.map(np.asarray, r.draw)
    m0, m = arm.mjx_model, randomizer.model(arm.mjx_model, r)
    links, dofs = randomizer.link_ids, randomizer.dof_ids
    np.testing.assert_allclose(m.body_mass[links], m0.body_mass[links] * d["mass_scale"], 1e-6)
    # the servos' gravity feed-forward keeps the nominal weights
    np.testing.assert_allclose(m.body_mass[links] * m.body_gravcomp[links], m0.body_mass[links])
    np.testing.assert_allclose(
        m.body_inertia[links], m0.body_inertia[links] * d["inertia_scale"][:, None], 1e-6
    )
    np.testing.assert_allclose(m.dof_damping[dofs], d["damping"])
    np.testing.assert_allclose(m.dof_frictionloss[dofs], d["frictionloss"])
    np.testing.assert_allclose(m.dof_armature[dofs], 0.1 * d["armature_scale"], 1e-6)
    kp = 1000.0 * d["kp_scale"]
    np.testing.assert_allclose(m.actuator_gainprm[randomizer.pos_act, 0], kp, 1e-6)
    np.testing.assert_allclose(m.actuator_biasprm[randomizer.pos_act, 1], -kp, 1e-6)
    kv = 200.0 * d["kv_scale"]
    np.testing.assert_allclose(m.actuator_gainprm[randomizer.vel_act, 0], kv, 1e-6)
    np.testing.assert_allclose(m.actuator_biasprm[randomizer.vel_act, 2], -kv, 1e-6)
    # MJX has friction-loss constraint rows only where the C model's friction is > 0
    assert np.all(arm.mjx_model._impl.dof_hasfrictionloss)


def test_train_cli_flags_reach_the_env_config():
    from mara_mjx.cli import train

    args = train.build_parser().parse_args(
        ["--env", "MARA", "--driver", "real", "--randomize", "--kp_scale", "0.7", "1.3",
         "--randomization.latency_steps", "0", "2"]
    )  # fmt: skip
    plan = train.resolve(args)
    env = mara_mjx.make(plan.env_name, **plan.env_overrides)
    assert env.config.driver == "real" and env.config.randomize
    assert env.config.randomization.kp_scale == (0.7, 1.3)
    assert env.config.randomization.latency_steps == (0, 2)
    assert env.config.randomization.mass_scale == RandomizeConfig().mass_scale
