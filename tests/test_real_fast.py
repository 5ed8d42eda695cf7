"""The real driver's contacts detected ('detect', the default: with the lean dynamics and
pose pass) against contacts solved ('physical', MJX): same trajectories while nothing
penetrates, collisions flagged at the same step, 'detect' through MJX, the randomised
driver, and the option's errors. (The lean dynamics alone: tests/test_dynamics.py.)

One compiled rollout per env: `STEPS` control steps of `N` arms from given start poses
toward given commands (one arm per scenario), so every test reuses the same programs.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mara_mjx
from mara_mjx.envs.randomize import RandomizeConfig

STEPS = 8
VELOCITY = 1.57  # rad/s, the servos' limit: the arms move 0.0785 rad per control step
SELF = np.array([1.82, 0.27, -1.45, 0.36, -2.5, 1.34])
# (start pose, command), rad. Each start is collision-free.
SCENARIOS = {
    # small random moves around the reset pose: nothing touches
    "free": (np.zeros(6), np.array([0.5, -0.4, 0.6, -0.5, 0.4, -0.6])),
    # motor1, motor4 and motor6 run into their joint limits at full speed (the servos
    # overshoot the limit by ~0.01 rad: the limit constraint acts)
    "limits": (np.array([3.0, 0.2, 0.0, 3.0, 0.0, -3.0]), np.array([4.0, 0.2, 0, 4.0, 0, -4.0])),
    # motor2 folds the arm down onto the table (contact near motor2 = 1.93 rad)
    "table": (np.array([0.0, 1.6, 0.0, 0.0, 0.0, 0.0]), np.array([0.0, 2.2, 0.0, 0.0, 0.0, 0.0])),
    # the gripper folds back into the arm (a capsule-capsule pair)
    "self": (0.8 * SELF, 1.05 * SELF),
}
FREE = ["free", "limits"]
HIT = ["table", "self"]


def make_rollout(env):
    """jit((q0 (N, 6), commands (N, 6), params) -> per step (STEPS, N, ...) q, qvel, ref,
    obs, collided, distance)."""

    def run(q0, commands, params):
        keys = jax.random.split(jax.random.key(0), q0.shape[0])
        states = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
        states = states.replace(q=q0, ref=q0)

        def body(s, _):
            s = jax.vmap(env.step)(s, commands)
            m = s.metrics
            return s, (s.q, s.qvel, s.ref, s.obs, m["collided"], m["distance"])

        return jax.lax.scan(body, states, None, length=STEPS)[1]

    return jax.jit(run)


def inputs():
    q0 = np.stack([SCENARIOS[k][0] for k in SCENARIOS]).astype(np.float32)
    commands = np.stack([SCENARIOS[k][1] for k in SCENARIOS]).astype(np.float32)
    return jnp.asarray(q0), jnp.asarray(commands)


def rows(names):
    return [list(SCENARIOS).index(k) for k in names]


@pytest.fixture(scope="module")
def rollouts():
    """{option: (env, the rollout's arrays)} for 'detect' and 'physical'."""
    out = {}
    for option in ("detect", "physical"):
        env = mara_mjx.make(
            "MARACollisionOrient", driver="real", velocity=VELOCITY, real_contacts=option
        )
        arrays = make_rollout(env)(*inputs(), env.default_params)
        out[option] = env, jax.tree.map(np.asarray, arrays)
    return out


def test_detect_matches_physical_while_nothing_penetrates(rollouts):
    """q, qvel, ref and the observation (q, TCP position error, orientation error, TCP
    velocity) over every step of the non-colliding scenarios."""
    (_, detect), (_, physical) = rollouts["detect"], rollouts["physical"]
    free = rows(FREE)
    assert detect[4][:, free].sum() == 0 and physical[4][:, free].sum() == 0
    # the lean dynamics and pose pass against MJX's: float32 rounding (measured on the
    # CPU: q 6e-8 rad, qvel 2.4e-7 rad/s, obs 7e-7)
    for name, a, b, tol in zip(
        ("q", "qvel", "ref", "obs"), detect[:4], physical[:4], (1e-6, 1e-5, 1e-6, 1e-5), strict=True
    ):
        np.testing.assert_allclose(a[:, free], b[:, free], rtol=0, atol=tol, err_msg=name)
    np.testing.assert_allclose(detect[5][:, free], physical[5][:, free], atol=1e-6)
    # the limits scenario does reach its limits (the joint-limit rows act in both)
    q = detect[0][:, rows(["limits"])[0]]
    assert q[:, 0].max() > 3.1416 and q[:, 3].max() > 3.14 and q[:, 5].min() < -3.14


def test_collisions_are_flagged_at_the_same_step(rollouts):
    """The table and the self-collision scenarios collide once, at the same step, and
    everything before that step and after the reset matches; only the colliding step's
    own observation differs (its final pose, reached without contact forces)."""
    (_, detect), (_, physical) = rollouts["detect"], rollouts["physical"]
    hit = rows(HIT)
    np.testing.assert_array_equal(detect[4][:, hit], physical[4][:, hit])
    steps = np.argmax(detect[4][:, hit], axis=0)
    assert np.all(detect[4][:, hit].sum(axis=0) == 1) and np.all(steps >= 2)
    for j, step in zip(hit, steps, strict=True):
        others = [t for t in range(STEPS) if t != step]
        for a, b in zip(detect[:4], physical[:4], strict=True):
            np.testing.assert_allclose(a[others, j], b[others, j], rtol=0, atol=1e-5)
        # back at the reset pose, at rest
        assert np.all(detect[0][step, j] == 0) and np.all(detect[1][step, j] == 0)


def test_detect_through_mjx_is_physical_until_contact(rollouts):
    """kinematics='mjx': 'detect' with `mjx.step` of the contact-free model and MJX's
    collision checks, the ones 'physical' reads from its contacts: the same flags and
    states at every step (the driver alone, stepped as the env does, so only
    `real_step` compiles)."""
    env = mara_mjx.make("MARACollision", driver="real", kinematics="mjx", velocity=VELOCITY)
    assert env.kinematics == "mjx" and env.config.real_contacts == "detect"
    arm = env.arm
    q0, commands = inputs()
    commands = jnp.clip(commands, arm.lower, arm.upper)
    step = jax.jit(
        jax.vmap(
            lambda q, qvel, ref, c: arm.real_step(
                q, qvel, ref, c, VELOCITY, env.n_substeps, contacts="detect", kinematics="mjx"
            )
        )
    )
    q, qvel, ref, flags, qs = q0, jnp.zeros_like(q0), q0, [], []
    for _ in range(STEPS):
        q, qvel, ref, pose = step(q, qvel, ref, commands)
        back = pose.collided[:, None]
        q, qvel, ref = (jnp.where(back, 0.0, x) for x in (q, qvel, ref))
        flags.append(np.asarray(pose.collided))
        qs.append(np.asarray(q))
    _, physical = rollouts["physical"]
    np.testing.assert_array_equal(np.stack(flags), physical[4] == 1)
    np.testing.assert_allclose(np.stack(qs), physical[0], rtol=0, atol=1e-6)


def test_randomised_real_driver_detects(rollouts):
    """randomize=True with 'detect': at nominal ranges the plain detect env exactly
    (colliding steps included, so its dynamics model is the contact-free one); at the
    default ranges finite, speed-limited, different, and still flagging the collisions."""
    env = mara_mjx.make("MARACollisionOrient", driver="real", velocity=VELOCITY, randomize=True)
    assert env.config.real_contacts == "detect"
    run = make_rollout(env)
    off = RandomizeConfig.off()
    nominal = jax.tree.map(np.asarray, run(*inputs(), env.make_params(randomization=off)))
    _, detect = rollouts["detect"]
    for a, b in zip(nominal, detect, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-5)
    drawn = jax.tree.map(np.asarray, run(*inputs(), env.default_params))
    assert all(np.all(np.isfinite(x)) for x in drawn)
    moved = np.abs(np.diff(drawn[2], axis=0)).max(axis=-1)[drawn[4][1:] == 0]  # no reset
    assert moved.max() <= VELOCITY * env.config.control_dt * 1.0001
    assert np.abs(drawn[0] - detect[0]).max() > 1e-4
    assert drawn[4][:, rows(HIT)].sum(axis=0).min() >= 1


@pytest.mark.parametrize("value", ["solve", "", None, "Physical"])
def test_bad_real_contacts_is_a_clear_error(value):
    valid = r"real_contacts=.* is not valid; choose one of \('detect', 'physical'\)"
    with pytest.raises(ValueError, match=valid):
        mara_mjx.make("MARA", driver="real", real_contacts=value)
