"""The four MARA tasks of gym-gazebo2 as one pure, jittable, vmappable environment.

    task                 reward                                   observation (size)
    MARA                 D - 1                                    q, e, v (12)
    MARAOrient           D O - 1                                  q, e, quat_err, v (16)
    MARACollision        D - 1 - C                                q, e, v (12)
    MARACollisionOrient  D O - 1 - C                              q, e, quat_err, v (16)

Observation (in this order):
    q          (6,)  rad     joint positions motor1..motor6
    e          (3,)  m       p_tcp - p_target, world frame
    quat_err   (4,)          quat_tcp (x) conj(quat_target), (w, x, y, z), quat_tcp with w >= 0
                             (Orient tasks only)
    v          (3,)  m/s     TCP linear velocity J_pos(q) qvel, world frame

Action (6,) rad: absolute joint position targets for motor1..motor6. Values outside
the joint limits are clipped to them; non-finite entries are replaced by the current
joint position (hold the pose) and counted in `metrics["nonfinite_actions"]`.

Episode: reset puts every joint at 0 with zero velocity. Episodes truncate after
`max_episode_steps` (1024); they terminate only if the physics state goes non-finite
(counted in `metrics["physics_blowup"]`; the state is put back at the reset pose).
On a collision (robot vs table, or two robot bodies not joined by a joint) the
step's observation and reward are those of the colliding pose, then the arm is put
back at the reset pose and the episode goes on; only the Collision tasks are
penalised.

Domain randomisation (`randomize=True`, envs/randomize.py): per-episode physics, joint
zero offsets, q noise and action latency; the observation is then the encoders' reading.

Usage:
    env = mara_mjx.make("MARACollisionOrient")
    state = jax.jit(env.reset)(key)
    state = jax.jit(env.step)(state, action)
    states = jax.vmap(env.step)(states, actions)
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.envs import ik, rewards
from mara_mjx.envs import randomize as rnd
from mara_mjx.envs.arm import Arm, ArmPose, load_model
from mara_mjx.envs.base import METRIC_KEYS, EnvConfig, EnvParams, EnvState
from mara_mjx.envs.geometry import quat_conj, quat_mul, quat_to_euler


@dataclasses.dataclass(frozen=True)
class Task:
    """What distinguishes the four tasks (static)."""

    name: str
    orientation: bool
    """Reward and observe the orientation error."""
    collision_penalty: bool
    """Penalise collisions in the reward."""
    beta: float
    """Orientation exponent used in the paper's experiments for this task."""


TASKS = {
    "MARA": Task("MARA", orientation=False, collision_penalty=False, beta=1.5),
    "MARAOrient": Task("MARAOrient", orientation=True, collision_penalty=False, beta=1.1),
    "MARACollision": Task("MARACollision", orientation=False, collision_penalty=True, beta=1.5),
    "MARACollisionOrient": Task(
        "MARACollisionOrient", orientation=True, collision_penalty=True, beta=1.5
    ),
}


def is_orient_task(env: Any) -> bool:
    """Whether `env` rewards and observes the orientation error (its `task` is an Orient
    Task; a random-target variant's too); False for an env without a task (a user's)."""
    return bool(getattr(getattr(env, "task", None), "orientation", False))


_ARMS: dict[bool, Arm] = {}


def _shared_arm(frictionloss: bool = False) -> Arm:
    """The MJX model is the same for every task: build it once per process.

    `frictionloss`: a model whose joints have MJX friction-loss constraint rows (MJX
    allocates them only for joints with a friction loss > 0 in the C model), so that the
    randomised real driver can set per-env friction; its nominal friction is
    `randomize.MIN_FRICTIONLOSS`, replaced by every draw."""
    if frictionloss not in _ARMS:
        mj_model = None
        if frictionloss:
            mj_model = load_model()
            mj_model.dof_frictionloss[:] = rnd.MIN_FRICTIONLOSS
        _ARMS[frictionloss] = Arm(mj_model)
    return _ARMS[frictionloss]


class MaraEnv:
    """One MARA task. See the module docstring for observation, action and episode."""

    metric_keys: tuple[str, ...] = METRIC_KEYS
    """The keys of `EnvState.metrics` (every one present from reset on)."""

    def __init__(self, task: Task, config: EnvConfig | None = None):
        self.task = task
        self.config = config if config is not None else default_config(task)
        cfg = self.config
        # the pose pass (lean or MJX); the real driver with physical contacts reads
        # its collisions from MJX's own contacts, so its poses come from MJX too
        physical = cfg.driver == "real" and cfg.real_contacts == "physical"
        self.kinematics = "mjx" if physical else cfg.kinematics
        self.arm = _shared_arm(frictionloss=cfg.randomize and cfg.driver == "real")
        # None: no randomisation, every step exactly the nominal env's
        self.randomizer = rnd.Randomizer(self.arm, cfg.randomization) if cfg.randomize else None
        if cfg.driver == "real":
            n = cfg.control_dt / self.arm.timestep
            if abs(n - round(n)) > 1e-6 or round(n) < 1:
                raise ValueError(
                    f"control_dt={cfg.control_dt} must be a positive multiple of the physics "
                    f"timestep {self.arm.timestep} s for the real driver"
                )
        self.n_substeps = max(1, round(cfg.control_dt / self.arm.timestep))
        if cfg.check_target:
            self._check_target(cfg)
        self.default_params = self.make_params()

    # ------------------------------------------------------------- properties
    @property
    def name(self) -> str:
        return self.task.name

    @property
    def observation_layout(self) -> list[dict[str, Any]]:
        """The observation's parts in order: name, [start, stop), units, description."""
        return observation_layout(self.task.orientation)

    @property
    def observation_size(self) -> int:
        return self.observation_layout[-1]["stop"]

    @property
    def action_size(self) -> int:
        return 6

    @property
    def joint_lower(self) -> np.ndarray:
        """(6,) rad."""
        return self.arm.lower.copy()

    @property
    def joint_upper(self) -> np.ndarray:
        """(6,) rad."""
        return self.arm.upper.copy()

    @property
    def max_episode_steps(self) -> int:
        return self.config.max_episode_steps

    def __repr__(self) -> str:
        return f"MaraEnv({self.task.name}, driver={self.config.driver!r})"

    def make_params(self, **overrides) -> EnvParams:
        """Params pytree from this env's config, with host-side validated overrides
        (target_pos, target_quat, velocity, reset_noise, alpha, beta, gamma, delta, eta,
        done, and `randomization` ranges of a randomised env: a RandomizeConfig whose
        latency fits the env's action buffer)."""
        cfg = self.config.replace(**overrides) if overrides else self.config
        if overrides and cfg.check_target and ({"target_pos", "target_quat"} & set(overrides)):
            self._check_target(cfg)
        if "randomization" in overrides and self.randomizer is None:
            raise ValueError(
                "randomization ranges need an env built with randomize=True "
                "(make(name, randomize=True))"
            )
        if "randomize" in overrides and cfg.randomize != self.config.randomize:
            raise ValueError(
                "randomize is fixed when the env is built (it changes the state's structure);"
                " make the env with randomize=True instead"
            )
        f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
        randomization = None
        if self.randomizer is not None:
            rnd.check_params(cfg.randomization, self.config.randomization)
            randomization = rnd.make_randomization(cfg.randomization)
        return EnvParams(
            target_pos=f32(cfg.target_pos),
            target_quat=f32(_unit(cfg.target_quat)),
            velocity=f32(cfg.velocity),
            reset_noise=f32(cfg.reset_noise),
            reward=jax.tree.map(f32, cfg.reward),
            randomization=randomization,
        )

    def _check_target(self, cfg: EnvConfig) -> None:
        """ValueError unless a collision-free pose inside the joint limits reaches cfg's
        target (its position, and its orientation for the Orient tasks)."""
        ik.check_reachable(
            self.arm.mj_model,
            np.asarray(cfg.target_pos),
            _unit(cfg.target_quat) if self.task.orientation else None,
        )

    # ------------------------------------------------------------------- API
    def reset(self, key: jax.Array, params: EnvParams | None = None) -> EnvState:
        """All joints at 0 (plus `reset_noise`), at rest. `params` defaults to
        `self.default_params`."""
        params = self.default_params if params is None else params
        key, noise_key = jax.random.split(key)
        noise = jax.random.uniform(noise_key, (6,), minval=-1.0, maxval=1.0)
        q = noise * params.reset_noise
        # The reset pose is collision-free (tests check it for the largest reset_noise),
        # so reset runs kinematics only: auto-reset then costs little.
        pose = self.arm.pose_with(q, self.kinematics, collide=False)
        history = None
        if self.randomizer is None:
            obs, metrics, _ = self._observe(q, pose, jnp.zeros(6), params)
        else:
            key, draw_key, sensor_key = jax.random.split(key, 3)
            params = params.replace(randomization=rnd.draw(draw_key, params.randomization))
            obs, metrics, _ = self._observe(q, pose, jnp.zeros(6), params)
            obs, q_meas = self._observe_measured(sensor_key, q, jnp.zeros(6), params, obs)
            history = self.randomizer.initial_history(q_meas)
        zero = jnp.zeros(())
        metrics.update(
            collided=zero,
            collisions=zero,
            nonfinite_actions=zero,
            physics_blowup=zero,
            episode_return=zero,
            episode_length=zero,
        )
        return EnvState(
            q=q,
            qvel=jnp.zeros(6),
            ref=q,
            obs=obs,
            reward=zero,
            terminated=jnp.array(False),
            truncated=jnp.array(False),
            step=jnp.zeros((), jnp.int32),
            key=key,
            params=params,
            metrics={k: metrics[k] for k in self.metric_keys},
            action_history=history,
        )

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        """One control period. `action` (6,) rad, absolute joint targets."""
        cfg, params = self.config, state.params
        action = jnp.asarray(action)
        if action.shape != (6,):
            raise ValueError(
                f"action must have shape (6,) (joint targets motor1..motor6), got {action.shape};"
                " use jax.vmap(env.step) or mara_mjx.BatchedEnv for batches"
            )
        randomizer, history, model = self.randomizer, state.action_history, None
        with jax.named_scope("action"):
            finite = jnp.isfinite(action)
            n_nonfinite = jnp.sum(~finite).astype(jnp.float32)
            if randomizer is None:
                command = jnp.where(finite, action, state.q)
                command = jnp.clip(command, self.arm.lower, self.arm.upper)
            else:
                # the policy commands in the encoders' frame (q + offset), k steps late
                offset = params.randomization.draw["offset"]
                command = jnp.where(finite, action, state.q + offset)
                command, history = randomizer.delay(history, command, params.randomization)
                command = jnp.clip(command, self.arm.lower, self.arm.upper) - offset
                command = jnp.clip(command, self.arm.lower, self.arm.upper)
                if cfg.driver == "real":
                    model = randomizer.model(
                        self.arm.dynamics_model(cfg.real_contacts), params.randomization
                    )

        if cfg.driver == "train":
            q, qvel, pose = self.arm.train_step(state.q, command, cfg.control_dt, self.kinematics)
            ref = command
        else:
            q, qvel, ref, pose = self.arm.real_step(
                state.q,
                state.qvel,
                state.ref,
                command,
                params.velocity,
                self.n_substeps,
                model,
                contacts=cfg.real_contacts,
                kinematics=self.kinematics,
            )

        key = state.key
        with jax.named_scope("observation"):
            obs, metrics, theta = self._observe(q, pose, qvel, params)
            if randomizer is not None:
                key, sensor_key = jax.random.split(key)
                obs, _ = self._observe_measured(sensor_key, q, qvel, params, obs)
        with jax.named_scope("reward"):
            reward = rewards.reward(
                metrics["distance"],
                theta,
                pose.collided,
                params.reward,
                orientation=self.task.orientation,
                collision=self.task.collision_penalty,
            )

        with jax.named_scope("reset_rules"):
            blowup = ~(
                jnp.all(jnp.isfinite(q)) & jnp.all(jnp.isfinite(qvel)) & jnp.all(jnp.isfinite(obs))
            )
            obs = jnp.where(blowup, state.obs, obs)
            reward = jnp.where(jnp.isfinite(reward), reward, 0.0)
            # Collision (or blow-up): back to the reset pose, at rest.
            back = pose.collided | blowup
            q = jnp.where(back, 0.0, q)
            qvel = jnp.where(back, 0.0, qvel)
            ref = jnp.where(back, 0.0, ref)

        step = state.step + 1
        collided = pose.collided.astype(jnp.float32)
        metrics.update(
            collided=collided,
            collisions=state.metrics["collisions"] + collided,
            nonfinite_actions=n_nonfinite,
            physics_blowup=blowup.astype(jnp.float32),
            episode_return=state.metrics["episode_return"] + reward,
            episode_length=step.astype(jnp.float32),
        )
        return state.replace(
            q=q,
            qvel=qvel,
            ref=ref,
            obs=obs,
            reward=reward,
            terminated=blowup,
            truncated=step >= cfg.max_episode_steps,
            step=step,
            key=key,
            metrics={k: metrics[k] for k in self.metric_keys},
            action_history=history,
        )

    # -------------------------------------------------------------- internals
    def _observe_measured(
        self, key: jax.Array, q: jax.Array, qvel: jax.Array, params: EnvParams, obs: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        """(the observation through the encoders, the measured q): q + offset + noise, and
        with measured_kinematics e, quat_err, v from the forward kinematics of that q."""
        q_meas = self.randomizer.measure(key, q, params.randomization)
        if self.config.randomization.measured_kinematics:
            pose = self.arm.pose_with(q_meas, self.kinematics, collide=False)
            obs, _, _ = self._observe(q_meas, pose, qvel, params)
            return obs, q_meas
        return obs.at[:6].set(q_meas), q_meas

    def _observe(
        self, q: jax.Array, pose: ArmPose, qvel: jax.Array, params: EnvParams
    ) -> tuple[jax.Array, dict[str, jax.Array], jax.Array]:
        """Observation, per-step error metrics and theta at pose `pose` (joint positions q)."""
        e = pose.tcp_pos - params.target_pos
        quat_err = quat_mul(pose.tcp_quat, quat_conj(params.target_quat))
        v = pose.tcp_jac @ qvel
        theta = rewards.orientation_angle(quat_err)
        values = {"q": q, "e": e, "quat_err": quat_err, "v": v}
        parts = [values[p["name"]] for p in self.observation_layout]
        metrics = {
            "distance": rewards.rms_distance(e),
            "position_error": jnp.abs(e),
            "angle": theta,
            "orientation_error": jnp.abs(quat_to_euler(quat_err)),
        }
        return jnp.concatenate(parts), metrics, theta


# name, size, units, description: the observation in order (the module docstring's table)
OBSERVATION_PARTS = (
    ("q", 6, "rad", "joint positions motor1..motor6"),
    ("e", 3, "m", "p_tcp - p_target, world frame"),
    ("quat_err", 4, "", "quat_tcp (x) conj(quat_target), (w, x, y, z), quat_tcp w >= 0"),
    ("v", 3, "m/s", "TCP linear velocity J_pos(q) qdot, world frame"),
)


def observation_layout(orientation: bool) -> list[dict[str, Any]]:
    """Names, slices [start, stop), units of the observation of a task with or without
    orientation (quat_err is in the Orient tasks only)."""
    layout, start = [], 0
    for name, size, units, description in OBSERVATION_PARTS:
        if name == "quat_err" and not orientation:
            continue
        layout.append(
            {"name": name, "start": start, "stop": start + size, "units": units,
             "description": description}
        )  # fmt: skip
        start += size
    return layout


def _unit(quat) -> np.ndarray:
    quat = np.asarray(quat, dtype=float)
    return quat / np.linalg.norm(quat)


def default_config(task: Task) -> EnvConfig:
    """The paper's settings for a task (per-task beta)."""
    cfg = EnvConfig()
    return cfg.replace(beta=task.beta)
