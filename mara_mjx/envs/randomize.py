"""Domain randomisation: per-environment physics, calibration, sensor noise and latency,
drawn at every reset (vmapped: no recompiles).

`RandomizeConfig` (static, frozen, validated) holds the ranges; `EnvConfig.randomize`
switches randomisation on and `EnvConfig.randomization` holds the config. The ranges go
into the traced params (`Randomization`, the field `EnvParams.randomization`), so a sweep
over them (a latency of 0, 1, 2, 3 steps; calibration offsets of growing size) reuses the
compiled reset and step. `reset` draws one episode's values into the same pytree; `step`
applies them:

    what                       applies to      how
    link masses, inertias      real driver     body_mass, body_inertia x scale per link
    joint damping              real driver     dof_damping (N m s/rad)
    joint friction loss        real driver     dof_frictionloss (N m; MuJoCo's dry friction)
    armature                   real driver     dof_armature x scale
    servo gains kp, kv         real driver     actuator gain/bias x scale per joint
    joint zero offsets         both drivers    the encoders read q + offset; the servos track
                                               the command in that frame (true q -> a - offset)
    observation noise on q     both drivers    Gaussian, std obs_noise_std, fresh every step
    action latency             both drivers    the command applied is the one given k control
                                               steps ago (k in latency_steps, per episode)

The train driver teleports, so the physics parameters do nothing there (they are still
drawn, so the params have one structure for both drivers).

What the policy observes: with `measured_kinematics` (default) every observation term comes
from the measured joints q_meas = q + offset + noise, as a ROS node computing e, quat_err and
v from /joint_states through the arm's forward kinematics would see it; the reward, the
metrics and collisions use the true pose. So a calibration offset moves the TCP away from
where the policy believes it is: an error no policy can remove (the sweep measures it).

The servos' gravity feed-forward keeps the nominal model's weights (body_gravcomp =
1 / mass_scale), as a real controller's gravity model is the nominal URDF's: the servo's PD
term carries the difference.

Control-period jitter is not modelled: the actions are absolute position targets that the
servos' own loop tracks between commands, so a late command (a ROS 2 timer's jitter is
around 1 ms of the 50 ms period, below the 5 ms physics step) only shifts when a target
starts, a fraction of the whole-step latency that `latency_steps` already covers.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mara_mjx.config import ConfigMixin

# The largest latency the action buffer may be built for (control steps, 50 ms each).
MAX_LATENCY_STEPS = 16
# The smallest friction loss (N m) the randomised model gets. MJX has a friction row for
# every joint of a model built with friction (envs/mara.py), and treats a row whose
# friction loss is exactly 0 as a stiff velocity constraint (its solver's linear zones
# require friction > 0; C MuJoCo has no row then): a draw of 0, e.g. RandomizeConfig.off(),
# would lock the joints. 1e-9 N m is dry friction of no consequence.
MIN_FRICTIONLOSS = 1e-9


@dataclasses.dataclass(frozen=True)
class RandomizeConfig(ConfigMixin):
    """Ranges of the domain randomisation (used when EnvConfig.randomize is true).

    Each range is (low, high), drawn uniformly per environment at every reset; low == high
    fixes a value. The defaults are what a real MARA is likely to differ from the model by.
    """

    mass_scale: tuple[float, float] = (0.9, 1.1)
    """Scale of each link's mass (motor1..motor6 links), drawn per link. The spec's URDF
    link masses sum to 21.9 kg against the datasheet's 21 kg (4%), and cables, covers and
    the gripper are not in the model: +-10%."""
    inertia_scale: tuple[float, float] = (0.9, 1.1)
    """Scale of each link's rotational inertia, drawn per link: CAD inertias carry the
    same uncertainty as the masses, +-10%."""
    damping: tuple[float, float] = (0.0, 2.0)
    """Viscous joint damping (N m s/rad) per joint. The source model has 0; harmonic-drive
    gearboxes add a viscous loss of the order of 1 N m s/rad at the output (Harmonic Drive
    CSG catalogue, no-load running torque against speed), small beside the servo's kv of
    200."""
    frictionloss: tuple[float, float] = (0.0, 2.0)
    """Dry friction (N m) per joint (MuJoCo frictionloss). Harmonic Drive CSG-20..32
    gearboxes at a 100:1 ratio list a no-load starting torque of roughly 0.5-3 N m at the
    output."""
    armature_scale: tuple[float, float] = (0.7, 1.3)
    """Scale of the joint armature (the model's 0.1 kg m^2, itself an estimate of a rotor
    inertia of ~1e-5 kg m^2 reflected through a 100:1 gear): +-30%."""
    kp_scale: tuple[float, float] = (0.8, 1.2)
    """Scale of each servo's position gain kp (1000 N m/rad): drive tuning differs from
    unit to unit; OpenAI's Dactyl randomised its P gains over 0.75-1.5x."""
    kv_scale: tuple[float, float] = (0.8, 1.2)
    """Scale of each servo's velocity gain kv (200 N m s/rad), as kp_scale."""
    calibration_offset: float = 0.001
    """Half-width (rad) of each joint's zero offset: the encoders read q + offset, drawn
    uniformly in [-w, w] per joint and episode. 1 mrad (0.06 deg) is a residual of a
    careful zero calibration; at the MARA's ~0.9 m reach 1 mrad moves the TCP by ~1 mm."""
    obs_noise_std: float = 0.0002
    """Standard deviation (rad) of Gaussian noise on each observed joint position, fresh
    every step: a few counts of a 17-bit absolute encoder (4.8e-5 rad per count) plus
    electrical noise."""
    latency_steps: tuple[int, int] = (0, 1)
    """Range of the action latency in control steps (50 ms each), per episode: the command
    applied is the one the policy gave k steps earlier. ROS 2 transport plus the drive's
    own loop add 5-30 ms to a 20 Hz loop, i.e. up to one step. The action buffer holds
    high + 1 commands, fixed when the env is built."""
    measured_kinematics: bool = True
    """Compute e, quat_err and v from the measured joints (q + offset + noise), as a ROS
    node using the arm's forward kinematics would; False: from the true TCP pose (an
    external tracker), only q is measured."""

    def __post_init__(self):
        for name in ("mass_scale", "inertia_scale", "armature_scale", "kp_scale", "kv_scale"):
            low, high = _range(name, getattr(self, name))
            if low <= 0:
                raise ValueError(
                    f"randomization.{name}={list(getattr(self, name))}: a scale must be > 0"
                )
            if high > 10:
                raise ValueError(
                    f"randomization.{name}={list(getattr(self, name))}: a scale above 10 is "
                    "not a plausible model error"
                )
        for name in ("damping", "frictionloss"):
            low, _ = _range(name, getattr(self, name))
            if low < 0:
                raise ValueError(
                    f"randomization.{name}={list(getattr(self, name))} must be >= 0 "
                    "(N m s/rad for damping, N m for frictionloss)"
                )
        for name, limit in (("calibration_offset", 0.2), ("obs_noise_std", 0.2)):
            value = getattr(self, name)
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not (ok and math.isfinite(value) and 0 <= value <= limit):
                raise ValueError(f"randomization.{name}={value!r} must be in [0, {limit}] rad")
        lat = self.latency_steps
        ints = isinstance(lat, tuple | list) and len(lat) == 2
        ints = ints and all(_is_int(k) for k in lat)
        if not (ints and 0 <= lat[0] <= lat[1] <= MAX_LATENCY_STEPS):
            raise ValueError(
                f"randomization.latency_steps={lat!r} must be two ints (low, high) with "
                f"0 <= low <= high <= {MAX_LATENCY_STEPS} (control steps)"
            )
        if not isinstance(self.measured_kinematics, bool):
            raise ValueError(
                f"randomization.measured_kinematics={self.measured_kinematics!r} must be a bool"
            )

    @classmethod
    def off(cls) -> RandomizeConfig:
        """Every range fixed at the nominal model (for sweeps that vary one thing)."""
        return cls(
            mass_scale=(1.0, 1.0),
            inertia_scale=(1.0, 1.0),
            damping=(0.0, 0.0),
            frictionloss=(0.0, 0.0),
            armature_scale=(1.0, 1.0),
            kp_scale=(1.0, 1.0),
            kv_scale=(1.0, 1.0),
            calibration_offset=0.0,
            obs_noise_std=0.0,
            latency_steps=(0, 0),
        )


def _is_int(x: Any) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


def _range(name: str, value: Any) -> tuple[float, float]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as e:
        raise ValueError(
            f"randomization.{name} must be two numbers (low, high), got {value!r}"
        ) from e
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(
            f"randomization.{name} must be two finite numbers (low, high), got {value!r}"
        )
    if arr[0] > arr[1]:
        raise ValueError(f"randomization.{name}={arr.tolist()}: low must be <= high")
    return float(arr[0]), float(arr[1])


RANGE_FIELDS = (
    "mass_scale",
    "inertia_scale",
    "damping",
    "frictionloss",
    "armature_scale",
    "kp_scale",
    "kv_scale",
)


@struct.dataclass
class Randomization:
    """The traced ranges (from RandomizeConfig) and this episode's draw, of one env."""

    ranges: dict[str, jax.Array]  # name -> (2,) low, high (RANGE_FIELDS)
    calibration_offset: jax.Array  # () rad, half-width
    obs_noise_std: jax.Array  # () rad
    latency_steps: jax.Array  # (2,) int32, low, high
    draw: dict[str, jax.Array]  # RANGE_FIELDS -> (6,), offset (6,) rad, latency () int32


def make_randomization(cfg: RandomizeConfig) -> Randomization:
    """Params of `cfg`; the draw holds the nominal model until the first reset."""
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    nominal = RandomizeConfig.off()
    return Randomization(
        ranges={name: f32(getattr(cfg, name)) for name in RANGE_FIELDS},
        calibration_offset=f32(cfg.calibration_offset),
        obs_noise_std=f32(cfg.obs_noise_std),
        latency_steps=jnp.asarray(cfg.latency_steps, jnp.int32),
        draw={
            **{name: jnp.full(6, getattr(nominal, name)[0], jnp.float32) for name in RANGE_FIELDS},
            "offset": jnp.zeros(6, jnp.float32),
            "latency": jnp.asarray(cfg.latency_steps[0], jnp.int32),
        },
    )


def draw(key: jax.Array, r: Randomization) -> Randomization:
    """One episode's values, uniform within the ranges (per joint / per link)."""
    keys = jax.random.split(key, len(RANGE_FIELDS) + 2)
    values = {
        name: jax.random.uniform(k, (6,), minval=r.ranges[name][0], maxval=r.ranges[name][1])
        for name, k in zip(RANGE_FIELDS, keys, strict=False)
    }
    values["offset"] = r.calibration_offset * jax.random.uniform(
        keys[-2], (6,), minval=-1.0, maxval=1.0
    )
    values["latency"] = jax.random.randint(
        keys[-1], (), r.latency_steps[0], r.latency_steps[1] + 1, dtype=jnp.int32
    )
    return r.replace(draw=values)


class Randomizer:
    """Applies a `Randomization` to one arm: ids and nominal values resolved once."""

    def __init__(self, arm, config: RandomizeConfig):
        self.config = config
        self.buffer_size = config.latency_steps[1] + 1
        m = arm.mj_model
        self.link_ids = np.array([m.jnt_bodyid[j] for j in arm.joint_ids])
        self.dof_ids = np.array([m.jnt_dofadr[j] for j in arm.joint_ids])
        names = [m.actuator(i).name for i in range(m.nu)]
        self.pos_act = np.array([names.index(f"motor{i}") for i in range(1, 7)])
        self.vel_act = np.array([names.index(f"motor{i}_vel") for i in range(1, 7)])
        self.mass0 = m.body_mass[self.link_ids].copy()
        self.inertia0 = m.body_inertia[self.link_ids].copy()
        self.gravcomp0 = m.body_gravcomp[self.link_ids].copy()
        self.armature0 = m.dof_armature[self.dof_ids].copy()
        self.kp0 = m.actuator_gainprm[self.pos_act, 0].copy()
        self.kv0 = m.actuator_gainprm[self.vel_act, 0].copy()
        # position actuator: bias = -kp q - kv_pos qdot (kv_pos = 0); velocity: -kv qdot
        if not np.allclose(m.actuator_biasprm[self.pos_act, 1], -self.kp0) or not np.allclose(
            m.actuator_biasprm[self.vel_act, 2], -self.kv0
        ):
            raise ValueError("the servo actuators are not position/velocity servos")

    def model(self, mjx_model, r: Randomization):
        """The MJX model with this episode's physics (call inside vmap: per-env fields)."""
        d = r.draw
        links, dofs = self.link_ids, self.dof_ids
        kp, kv = self.kp0 * d["kp_scale"], self.kv0 * d["kv_scale"]
        gain = mjx_model.actuator_gainprm
        gain = gain.at[self.pos_act, 0].set(kp).at[self.vel_act, 0].set(kv)
        bias = mjx_model.actuator_biasprm
        bias = bias.at[self.pos_act, 1].set(-kp).at[self.vel_act, 2].set(-kv)
        return mjx_model.replace(
            body_mass=mjx_model.body_mass.at[links].set(self.mass0 * d["mass_scale"]),
            body_inertia=mjx_model.body_inertia.at[links].set(
                self.inertia0 * d["inertia_scale"][:, None]
            ),
            # the gravity feed-forward keeps the nominal weights (see the module docstring)
            body_gravcomp=mjx_model.body_gravcomp.at[links].set(self.gravcomp0 / d["mass_scale"]),
            dof_damping=mjx_model.dof_damping.at[dofs].set(d["damping"]),
            dof_frictionloss=mjx_model.dof_frictionloss.at[dofs].set(
                jnp.maximum(d["frictionloss"], MIN_FRICTIONLOSS)
            ),
            dof_armature=mjx_model.dof_armature.at[dofs].set(self.armature0 * d["armature_scale"]),
            actuator_gainprm=gain,
            actuator_biasprm=bias,
        )

    def initial_history(self, hold: jax.Array) -> jax.Array:
        """(buffer_size, 6): every pending command holds `hold` (the measured pose)."""
        return jnp.broadcast_to(hold, (self.buffer_size, 6))

    def delay(
        self, history: jax.Array, command: jax.Array, r: Randomization
    ) -> tuple[jax.Array, jax.Array]:
        """Push `command`; return (the command given `latency` steps ago, new history)."""
        history = jnp.concatenate([command[None], history[:-1]])
        latency = jnp.clip(r.draw["latency"], 0, self.buffer_size - 1)
        return history[latency], history

    def measure(self, key: jax.Array, q: jax.Array, r: Randomization) -> jax.Array:
        """The encoders' reading of q (6,): q + offset + noise."""
        noise = jax.random.normal(key, (6,)) * r.obs_noise_std
        return q + r.draw["offset"] + noise


def check_params(config: RandomizeConfig, built: RandomizeConfig) -> None:
    """ValueError if params of `config` do not fit an env built for `built` (the action
    buffer's size is fixed at construction)."""
    if config.latency_steps[1] > built.latency_steps[1]:
        raise ValueError(
            f"randomization.latency_steps={list(config.latency_steps)} exceeds the action "
            f"buffer this env was built with (latency up to {built.latency_steps[1]} steps); "
            "build the env with the largest latency you will use"
        )
