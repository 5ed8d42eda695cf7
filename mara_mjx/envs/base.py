"""The environment contract: the `Env` protocol, config (static), params (traced), state
(episode data).

* `Env` is what every consumer relies on: the batching layer (`BatchedEnv`), the
  gymnasium and brax adapters, PPO (`make_train`), evaluation, play and the tests' toy
  env. Any object with these members works with all of them; `MaraEnv` is the one this
  package ships. Its state must carry `obs`, `reward`, `terminated`, `truncated`, `key`,
  `params` and `metrics` holding at least `episode_return`, `episode_length` and
  `collisions` (`EnvStateLike`).

* `EnvConfig` is fixed when an env is built: anything that changes shapes or Python
  control flow (driver, horizon, control period) plus the defaults of the params.
  It is a frozen dataclass validated in `__post_init__`; `make(name, **overrides)`
  replaces its fields.
* `EnvParams` is a pytree of arrays passed to `reset` and kept in the state, so a
  sweep or a per-environment randomisation of the target, the reward
  hyperparameters or the servo speed never recompiles.
* `EnvState` is a typed pytree with a fixed structure from `reset` on.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal, Protocol, runtime_checkable

import jax
import numpy as np
from flax import struct

from mara_mjx.config import check_vector, is_finite
from mara_mjx.envs.arm import MAX_JOINT_SPEED
from mara_mjx.envs.randomize import RandomizeConfig
from mara_mjx.envs.rewards import RewardParams, check_reward_params


@runtime_checkable
class EnvStateLike(Protocol):
    """What consumers read from an env's state (a pytree; batched: leading (N,) axis)."""

    obs: jax.Array  # (observation_size,) float32
    reward: jax.Array  # ()
    terminated: jax.Array  # () bool: a real end (no bootstrap)
    truncated: jax.Array  # () bool: the horizon (GAE bootstraps through it)
    key: jax.Array  # PRNG key of this environment (auto-reset draws from it)
    params: Any  # the traced params the episode runs with
    metrics: dict[str, jax.Array]  # >= episode_return, episode_length, collisions


@runtime_checkable
class Env(Protocol):
    """A pure, jittable, vmappable environment: the contract of every consumer.

    `reset(key, params)` and `step(state, action)` are pure functions of pytrees (no
    Python state changes inside), so `jax.jit` and `jax.vmap` apply to them directly.
    """

    @property
    def observation_size(self) -> int:
        """Length of `state.obs`."""
        ...

    @property
    def action_size(self) -> int:
        """Length of an action."""
        ...

    @property
    def max_episode_steps(self) -> int:
        """The horizon: `truncated` is set at this step."""
        ...

    default_params: Any
    """The params pytree `reset` uses when given None."""

    def reset(self, key: jax.Array, params: Any = None) -> EnvStateLike:
        """A new episode's first state (params None: `default_params`)."""
        ...

    def step(self, state: Any, action: jax.Array) -> EnvStateLike:
        """The next state after `action` (action_size,)."""
        ...


DRIVERS = ("train", "real")
KINEMATICS = ("mjx", "lean", "fused")
REAL_CONTACTS = ("detect", "physical")
DEFAULT_TARGET_POS = (-0.40028, 0.095615, 0.72466)
DEFAULT_TARGET_QUAT = (0.0, 0.7071068, 0.7071068, 0.0)
# Random-target tasks (envs/random_target.py): the default working volume, 30 x 50 x 20 cm
# in front of the robot (the -x side, where the spec's target lies), 5.5 to 25.5 cm
# above the table top. It holds DEFAULT_TARGET_POS, and every cell of a 5 x 5 x 5 grid
# over it (6 x 10 x 4 cm) holds collision-free poses with the tool within 30 deg of
# pointing down (tests/test_random_target.py); with the tool exactly down the arm
# reaches 0.45 m from the base axis at z = 0.7 m but only 0.30 m at z = 0.9 m.
DEFAULT_TARGET_MIN = (-0.50, -0.25, 0.70)
DEFAULT_TARGET_MAX = (-0.20, 0.25, 0.90)
DEFAULT_TARGET_SPREAD_DEG = 30.0
MAX_TARGET_TABLE_SIZE = 65536

# Every key of EnvState.metrics, present from reset on.
METRIC_KEYS = (
    "distance",  # () m, RMS of the position error (the reward's d)
    "position_error",  # (3,) m, |e_x|, |e_y|, |e_z|
    "angle",  # () rad, orientation error angle theta
    "orientation_error",  # (3,) rad, |roll|, |pitch|, |yaw| of quat_err
    "collided",  # () 0/1, this step collided (the arm was put back at the reset pose)
    "collisions",  # () number of collisions so far in this episode
    "nonfinite_actions",  # () number of non-finite action entries replaced in this step
    "physics_blowup",  # () 0/1, the physics state went non-finite (terminates)
    "episode_return",  # () running sum of rewards in this episode
    "episode_length",  # () steps so far in this episode
)


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Configuration of one MARA task. Every field can be overridden in `make`.

    Like every config (`mara_mjx.config`): frozen, one docstring per field (the CLIs'
    help), validated in `__post_init__` with errors naming the field."""

    driver: Literal["train", "real"] = "train"
    """'train': joints reach commands at once (kinematics + collision only, the paper's
    training driver). 'real': velocity-limited position servos and MJX dynamics."""
    kinematics: Literal["mjx", "lean", "fused"] = "lean"
    """Plain jnp or MJX for the arm's mechanics. 'lean' (the default): each pose and
    collision bit from the chain's six transforms and the 24 pairs' exact signed
    distances (mara_mjx/envs/lean.py; TCP pose within 1e-6 m of MJX's, collision flags
    as C MuJoCo's beyond float32 precision of contact, where MJX's capsule-box test
    differs; 1.4x the train driver's env steps/s and a faster compile:
    benchmarks/NOTES.md section 17), and the real driver's dynamics with
    real_contacts='detect' from mara_mjx/envs/dynamics.py (mjx.step's to float32
    rounding, tests/test_dynamics.py; no while loop or scatter). 'mjx': `mjx.kinematics`
    + `mjx.collision`, and `mjx.step`, the reference. 'fused': the lean pass's maths
    written per scalar of the batch (mara_mjx/envs/fused_pose.py), which XLA fuses into a
    few kernels (the pose pass 12x faster on an H100, a longer compile; benchmarks/NOTES.md
    section 68): the same numbers as 'lean' to float32 rounding, not the same bits, so
    not the default, whose learning rows were measured with 'lean'. With
    real_contacts='physical' the real driver is MJX's whatever this says."""
    real_contacts: Literal["detect", "physical"] = "detect"
    """Real driver: how contacts enter the dynamics. 'detect' (the default): detected,
    not solved. The dynamics leave contacts out (joint limits, and the randomised
    friction loss, still act), and every physics substep's start pose and the final
    pose are checked for penetration by the `kinematics` pass. A collision puts the arm
    back at the reset pose in every task, and contact forces act only once a pair
    penetrates, so the trajectories, collided flags and resets are those of 'physical'
    (tests/test_real_fast.py); only a colliding step's own observation and reward
    differ (its final pose, reached without the contact pushing back). 'physical':
    MJX solves the contact forces at every substep, as the spec's section 5 words it,
    several times slower (benchmarks/real_driver_speed.py). Ignored by the train
    driver."""
    max_episode_steps: int = 1024
    """Horizon: the episode truncates after this many steps."""
    control_dt: float = 0.05
    """Control period (s): one env step. The real driver splits it into physics steps of
    the model's 5 ms timestep; the train driver uses it for qvel = (q' - q) / control_dt."""
    velocity: float = 0.5
    """Real driver: speed (rad/s) at which each servo reference moves toward the command,
    in (0, 1.57]. Ignored by the train driver."""
    target_pos: tuple[float, float, float] = DEFAULT_TARGET_POS
    """Target TCP position (m, world frame). Must be reachable without collision."""
    target_quat: tuple[float, float, float, float] = DEFAULT_TARGET_QUAT
    """Target TCP orientation (w, x, y, z), normalised on use. Orient tasks only."""
    reward: RewardParams = dataclasses.field(default_factory=RewardParams)
    """Reward hyperparameters (alpha, beta, gamma, delta, eta, done), each within its
    valid range (mara_mjx.envs.rewards.RANGES; a clear error outside it)."""
    reset_noise: float = 0.0
    """Half-width (rad) of a uniform perturbation of the reset joint positions. 0 (the
    paper's reset, all joints at 0) for training; evaluation uses a small value so that
    its episodes differ, as the paper's Gazebo runs did."""
    check_target: bool = True
    """Verify at construction, by inverse kinematics, that the target is reachable."""
    target_min: tuple[float, float, float] = DEFAULT_TARGET_MIN
    """Random-target tasks: lower corner (m, world frame) of the box each episode's target
    TCP position is drawn from."""
    target_max: tuple[float, float, float] = DEFAULT_TARGET_MAX
    """Random-target tasks: upper corner (m, world frame) of that box."""
    target_spread_deg: float = DEFAULT_TARGET_SPREAD_DEG
    """Random-target tasks: largest rotation (deg, in [0, 180]) of a drawn target
    orientation away from target_quat (tool pointing down by default); 180 allows any
    orientation, the default of the position-only tasks."""
    target_table_size: int = 1024
    """Random-target tasks: poses in the table the targets are drawn from (fixed when the
    env is built: the params hold the table, so changing the region does not recompile)."""
    target_seed: int = 0
    """Random-target tasks: seed of the pose table (evaluation poses come from a
    different, independent stream)."""
    randomize: bool = False
    """Domain randomisation: draw masses, inertias, damping, friction, armature, servo
    gains (real driver), joint zero offsets, observation noise and action latency (both
    drivers) per environment at every reset, within the `randomization` ranges
    (mara_mjx/envs/randomize.py). False: the nominal model, exactly."""
    randomization: RandomizeConfig = dataclasses.field(default_factory=RandomizeConfig)
    """The ranges of the domain randomisation (RandomizeConfig), used when randomize."""

    def __post_init__(self):
        if self.driver not in DRIVERS:
            raise ValueError(f"driver={self.driver!r} is not valid; choose one of {DRIVERS}")
        if self.kinematics not in KINEMATICS:
            raise ValueError(
                f"kinematics={self.kinematics!r} is not valid; choose one of {KINEMATICS}"
            )
        if self.real_contacts not in REAL_CONTACTS:
            raise ValueError(
                f"real_contacts={self.real_contacts!r} is not valid; choose one of {REAL_CONTACTS}"
            )
        if not isinstance(self.max_episode_steps, int) or isinstance(self.max_episode_steps, bool):
            raise ValueError(
                f"max_episode_steps must be a positive int, got {self.max_episode_steps!r}"
            )
        if not 1 <= self.max_episode_steps < 2**30:
            raise ValueError(f"max_episode_steps={self.max_episode_steps} must be in [1, 2**30)")
        if not (is_finite(self.control_dt) and self.control_dt > 0):
            raise ValueError(f"control_dt={self.control_dt!r} must be a finite number > 0 (s)")
        if not (is_finite(self.velocity) and 0 < self.velocity <= MAX_JOINT_SPEED):
            raise ValueError(
                f"velocity={self.velocity!r} is not valid: the real driver's servo speed must be "
                f"in (0, {MAX_JOINT_SPEED}] rad/s (the MARA joint speed limit)"
            )
        if not (is_finite(self.reset_noise) and 0 <= self.reset_noise <= 0.5):
            raise ValueError(f"reset_noise={self.reset_noise!r} must be in [0, 0.5] rad")
        check_vector("target_pos", self.target_pos, 3)
        check_vector("target_quat", self.target_quat, 4)
        if np.linalg.norm(self.target_quat) < 1e-6:
            raise ValueError("target_quat must be a non-zero quaternion (w, x, y, z)")
        check_vector("target_min", self.target_min, 3)
        check_vector("target_max", self.target_max, 3)
        if not np.all(np.asarray(self.target_min) < np.asarray(self.target_max)):
            raise ValueError(
                f"target_min={list(self.target_min)} must be below target_max="
                f"{list(self.target_max)} on every axis (x, y, z; m, world frame)"
            )
        if not (is_finite(self.target_spread_deg) and 0 <= self.target_spread_deg <= 180):
            raise ValueError(
                f"target_spread_deg={self.target_spread_deg!r} must be in [0, 180] degrees"
            )
        size, seed = self.target_table_size, self.target_seed
        if not (_is_int(size) and 1 <= size <= MAX_TARGET_TABLE_SIZE):
            raise ValueError(
                f"target_table_size={size!r} must be an int in [1, {MAX_TARGET_TABLE_SIZE}]"
            )
        if not (_is_int(seed) and 0 <= seed < 2**63):
            raise ValueError(f"target_seed={seed!r} must be an int in [0, 2**63)")
        if not isinstance(self.randomize, bool):
            raise ValueError(f"randomize={self.randomize!r} must be true or false")
        if not isinstance(self.randomization, RandomizeConfig):
            raise ValueError(
                "randomization must be a mara_mjx.envs.randomize.RandomizeConfig, got "
                f"{type(self.randomization).__name__}"
            )
        if not isinstance(self.reward, RewardParams):
            raise ValueError(
                "reward must be a mara_mjx.envs.rewards.RewardParams, got "
                f"{type(self.reward).__name__}"
            )
        check_reward_params(self.reward)  # also jax arrays, which RewardParams skips

    def replace(self, **overrides: Any) -> EnvConfig:
        """A new config with fields replaced; unknown names raise a clear error. Reward
        hyperparameters may be given by name (alpha=..., beta=...) or as `reward=`."""
        fields = {f.name for f in dataclasses.fields(self)}
        reward_fields = {f.name for f in dataclasses.fields(RewardParams)}
        reward_overrides = {k: overrides.pop(k) for k in list(overrides) if k in reward_fields}
        unknown = sorted(set(overrides) - fields)
        if unknown:
            raise ValueError(
                f"unknown env option(s) {unknown}; valid options are "
                f"{sorted(fields | reward_fields)}"
            )
        if reward_overrides:
            base = overrides.get("reward", self.reward)
            overrides["reward"] = base.replace(**{k: float(v) for k, v in reward_overrides.items()})
        if isinstance(overrides.get("randomization"), dict):  # some fields, or to_dict()'s
            fields = {
                k: tuple(v) if isinstance(v, list) else v
                for k, v in overrides["randomization"].items()
            }
            overrides["randomization"] = self.randomization.replace(**fields)
        for name in ("target_pos", "target_quat", "target_min", "target_max"):
            if name in overrides:
                overrides[name] = tuple(float(x) for x in np.asarray(overrides[name]).ravel())
        return dataclasses.replace(self, **overrides)

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["reward"] = {
            f.name: float(getattr(self.reward, f.name)) for f in dataclasses.fields(RewardParams)
        }
        return out


def _is_int(x: Any) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


@struct.dataclass
class EnvParams:
    """Traced parameters of one environment (vmap over them to randomise per env)."""

    target_pos: jax.Array  # (3,) m, world frame
    target_quat: jax.Array  # (4,) (w, x, y, z), unit
    velocity: jax.Array  # () rad/s, real driver servo speed
    reset_noise: jax.Array  # () rad, half-width of the uniform reset perturbation
    reward: RewardParams
    randomization: Any  # envs.randomize.Randomization, or None (no randomisation)


@struct.dataclass
class EnvState:
    """One environment's state. Batched states have a leading (N,) axis on every leaf."""

    q: jax.Array  # (6,) rad, joint positions
    qvel: jax.Array  # (6,) rad/s, joint velocities
    ref: jax.Array  # (6,) rad, servo references (real driver)
    obs: jax.Array  # (observation_size,)
    reward: jax.Array  # ()
    terminated: jax.Array  # () bool: physics blow-up only
    truncated: jax.Array  # () bool: horizon reached
    step: jax.Array  # () int32, steps taken in this episode (<= max_episode_steps)
    key: jax.Array  # PRNG key of this environment
    params: EnvParams
    metrics: dict[str, jax.Array]
    action_history: Any = None
    """(buffer, 6) rad: the last commands, newest first (randomised latency only; else
    None)."""

    @property
    def done(self) -> jax.Array:
        return self.terminated | self.truncated
