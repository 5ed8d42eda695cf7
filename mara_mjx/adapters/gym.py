"""Gymnasium adapter: the MARA tasks as `gymnasium.Env` (here) and
`gymnasium.vector.VectorEnv` (`mara_mjx.adapters.gym_vector.MaraVectorEnv`), and the ids.

Host side, numpy in and out; the physics runs in JAX (jitted once per instance).

    import gymnasium, mara_mjx                      # importing mara_mjx registers the ids
    env = gymnasium.make("mara_mjx/MARACollisionOrient-v0", driver="real", velocity=0.3)
    obs, info = env.reset(seed=0)                   # obs (16,) float32
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

    envs = gymnasium.make_vec("mara_mjx/MARA-v0", num_envs=64,
                              vectorization_mode="vector_entry_point")
    obs, infos = envs.reset(seed=0)                 # (64, 12) float32, one batched device call

Registered ids: `mara_mjx/MARA-v0`, `mara_mjx/MARAOrient-v0`, `mara_mjx/MARACollision-v0`,
`mara_mjx/MARACollisionOrient-v0`, and the random-target tasks (a new target pose every
episode) `mara_mjx/MARARandomTarget-v0`, `mara_mjx/MARAOrientRandomTarget-v0`,
`mara_mjx/MARACollisionRandomTarget-v0`, `mara_mjx/MARACollisionOrientRandomTarget-v0`;
Keyword arguments are the env options of `mara_mjx.make` (fields of `mara_mjx.EnvConfig`:
driver, max_episode_steps, velocity, target_pos, target_quat, reset_noise, alpha, ...,
done; target_min, target_max, target_spread_deg, ... for the random-target tasks), and one
per name you `mara_mjx.register`.

Horizon: the ids are registered without a gymnasium `TimeLimit`; truncation comes from
the env's own `max_episode_steps` (1024 by default). `MaraGymEnv(task,
max_episode_steps=k)` and `gymnasium.make_vec(id, ..., max_episode_steps=k)` set that
horizon. `gymnasium.make(id, max_episode_steps=k)` cannot: gymnasium's `make` keeps that
argument for itself and wraps the env in its `TimeLimit(k)` (episodes then end at
min(k, env horizon), the env's info unaware of k); use `MaraGymEnv` directly to set the
env's own horizon.

Observation: `Box(-inf, inf, (12,) or (16,), float32)`, layout in `mara_mjx.envs.mara`
(q rad, e m, [quat_err], v m/s). Action: `Box(joint_lower, joint_upper, (6,), float32)`,
absolute joint targets (rad). Values outside the box are clipped by the env; a wrong
shape, a non-numeric dtype or a NaN/inf entry raises `ValueError` on the host.
Reward: the task reward (Python float). `info`: the env's metrics (`mara_mjx.EnvState`
metrics: distance m, position_error (3,) m, angle rad, ...) as numpy.

`reset(seed=s)` seeds a JAX key (`jax.random.key(s)`); each reset draws a new subkey
from it, so `reset_noise > 0` gives different episodes. `reset(options={...})` accepts
the traced params of `env.make_params` (target_pos, target_quat, velocity, reset_noise,
alpha, beta, gamma, delta, eta, done): they change without recompiling.

Rendering (`MaraGymEnv` only; C MuJoCo on the host, `mara_mjx.viz.render`):
`render_mode="rgb_array"`: `render()` returns a (height, width, 3) uint8 frame (640 x 480
unless `width=`/`height=` are given; `camera=` a model camera name, default a free camera
on the workspace) of the arm at the current joint positions, with the TCP site and the
target marker at the env's target; offscreen through EGL or OSMesa (MUJOCO_GL if set).
`render_mode="human"`: the interactive MuJoCo viewer (needs a desktop), updated at every
reset and step. Nothing is drawn, and no OpenGL context or window exists, before the
first `render()` (human: the first reset): stable-baselines3's `make_vec_env` builds
every env with render_mode="rgb_array", and a GL context made current in a process that
then imports triton (torch does, when SB3 trains) crashes it. `metadata["render_fps"]`
is 1 / control_dt (20 by default). `check_env` builds every declared render mode, the
viewer included, so run it with `skip_render_check=True` on a machine without a display.

Vector env autoreset (`autoreset_mode=`, declared in `metadata["autoreset_mode"]`):
  * "next_step" (default; gymnasium's own mode, which its vector wrappers such as
    `NormalizeObservation` require and CleanRL and SB3 assume): the step that ends an
    episode returns that episode's final observation with terminated/truncated set and
    its metrics in `infos`; at the next `step` that env ignores its action and returns
    the new episode's first observation, reward 0, terminated = truncated = False.
  * "same_step" (how `mara_mjx.BatchedEnv` resets on the device): the step that ends an
    episode returns that step's reward, terminated and truncated, the FIRST observation
    of the next episode as `obs` (its metrics in `infos`), and for the envs that ended
    `infos["final_obs"]` (object array of (obs,) arrays, None elsewhere; mask
    `infos["_final_obs"]`) and `infos["final_info"]` (the ending step's metrics).
Either way the physics runs on the device in one jitted call per step. Episode
statistics: wrap with `gymnasium.wrappers.vector.RecordEpisodeStatistics` (infos
["episode"] with "r", "l", "t"); the ending step's metrics also hold `episode_return`,
`episode_length` and `collisions`. `reset(seed=s)` splits the N env keys from one int;
`reset(seed=[s_0, ..., s_N-1])` gives env i the key `jax.random.key(s_i)`.

Ids: every name of `mara_mjx.registered()` gets `mara_mjx/<name>-v0`, including names
added later with `mara_mjx.register` (the registry calls `register_gym_id`).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import numpy as np
from gymnasium import spaces

from mara_mjx.envs import make
from mara_mjx.envs.registry import on_register

TASK_NAMES = ("MARA", "MARAOrient", "MARACollision", "MARACollisionOrient")
RANDOM_TARGET_TASK_NAMES = tuple(f"{task}RandomTarget" for task in TASK_NAMES)
NAMESPACE = "mara_mjx"
VERSION = 0


def gym_id(task: str) -> str:
    """'mara_mjx/<task>-v0'."""
    return f"{NAMESPACE}/{task}-v{VERSION}"


def check_action(action: Any, shape: tuple[int, ...]) -> np.ndarray:
    """`action` as a float32 array of `shape` (rad); ValueError naming what is wrong."""
    try:
        arr = np.asarray(action)
    except (TypeError, ValueError) as e:
        raise ValueError(f"action must be an array of shape {shape} (rad): {e}") from e
    if arr.dtype.kind not in "biuf":
        raise ValueError(
            f"action must be numeric joint targets (rad, float32), got dtype {arr.dtype}"
        )
    if arr.shape != shape:
        raise ValueError(f"action must have shape {shape} (joint targets, rad), got {arr.shape}")
    with np.errstate(over="ignore", invalid="ignore"):  # overflow to inf is reported below
        arr = arr.astype(np.float32)
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr)).tolist()
        raise ValueError(f"action has non-finite (NaN or inf) entries at indices {bad}")
    return arr


def _spaces(env: Any) -> tuple[spaces.Box, spaces.Box]:
    obs_space = spaces.Box(-np.inf, np.inf, (env.observation_size,), np.float32)
    action_space = spaces.Box(
        env.joint_lower.astype(np.float32),
        env.joint_upper.astype(np.float32),
        (env.action_size,),
        np.float32,
    )
    return obs_space, action_space


RENDER_MODES = ("rgb_array", "human")


def _check_render_mode(render_mode: str | None, valid: tuple[str, ...], where: str) -> None:
    if render_mode is not None and render_mode not in valid:
        choices = ", ".join(repr(m) for m in (None, *valid))
        raise ValueError(f"render_mode={render_mode!r} is not supported by {where}; use {choices}")


class MaraGymEnv(gymnasium.Env):
    """One MARA task as a `gymnasium.Env` (host numpy in and out, JAX inside).

    Args:
      task: a name of `mara_mjx.registered()` ("MARA", "MARAOrient", "MARACollision",
        "MARACollisionOrient", or your own registered variant).
      render_mode: None, "rgb_array" (frames from `render()`) or "human" (the MuJoCo
        viewer on a desktop).
      width, height: rgb_array frame size in pixels (at most 1280 x 720).
      camera: rgb_array camera: None (a free camera on the workspace) or a model camera
        ("front", "side").
      **overrides: env options of `mara_mjx.make` (EnvConfig fields), e.g.
        max_episode_steps=256, driver="real", velocity=0.3, target_pos=(x, y, z).

    `reset` and `step` are `jax.jit(env.reset)` and `jax.jit(env.step)`, compiled once
    per instance at the first call (or at `precompile()`). The offscreen GL context
    (rgb_array) or the viewer's window (human) is made at the first `render()`, where a
    machine that cannot render fails (`RenderError`); a bad size or camera fails here,
    and so does human mode without a display.
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 20}

    def __init__(
        self,
        task: str = "MARA",
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | None = None,
        **overrides: Any,
    ):
        _check_render_mode(render_mode, RENDER_MODES, "MaraGymEnv")
        self.env = make(task, **overrides)
        self.task = task
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.env.config.control_dt}
        self.observation_space, self.action_space = _spaces(self.env)
        self._renderer = self._viewer = None
        if render_mode == "rgb_array":
            from mara_mjx.viz.render import ArmRenderer

            self._renderer = ArmRenderer(width, height, camera)  # no GL context yet
            self._render_args = (width, height, camera)
        elif render_mode == "human":
            from mara_mjx.viz.render import check_display

            check_display()  # the window itself opens at the first render()
        self._jit_reset = jax.jit(self.env.reset)
        self._jit_step = jax.jit(self.env.step)
        self._key: jax.Array | None = None
        self.state = None  # mara_mjx.EnvState after reset

    @property
    def max_episode_steps(self) -> int:
        """The env's own horizon (steps)."""
        return self.env.max_episode_steps

    def precompile(self) -> MaraGymEnv:
        """Compile reset and step now (they compile at first use otherwise). The env's
        episode is untouched. Returns self."""
        state = self._jit_reset(jax.random.key(0), self.env.default_params)
        jax.block_until_ready(self._jit_step(state, np.zeros(self.env.action_size, np.float32)))
        return self

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode. `seed` (int) seeds the JAX key; `options`: params overrides
        (see `MaraEnv.make_params`). Returns obs (obs_size,) float32 and info."""
        super().reset(seed=seed)
        params = self.env.make_params(**options) if options else self.env.default_params
        if seed is not None:
            self._key = jax.random.key(seed)
        elif self._key is None:
            self._key = jax.random.key(int(self.np_random.integers(2**31)))
        self._key, reset_key = jax.random.split(self._key)
        self.state = self._jit_reset(reset_key, params)
        obs, metrics = jax.device_get((self.state.obs, self.state.metrics))
        if self.render_mode == "human":
            self.render()
        return np.array(obs, np.float32), _numpy_info(metrics)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply `action` (6,) rad. Returns obs (obs_size,) float32, reward, terminated
        (physics blow-up), truncated (horizon reached) and info (metrics as numpy)."""
        if self.state is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        action = check_action(action, self.action_space.shape)
        self.state = self._jit_step(self.state, action)
        s = self.state
        obs, reward, terminated, truncated, metrics = jax.device_get(
            (s.obs, s.reward, s.terminated, s.truncated, s.metrics)
        )
        if self.render_mode == "human":
            self.render()
        return (
            np.array(obs, np.float32),
            float(reward),
            bool(terminated),
            bool(truncated),
            _numpy_info(metrics),
        )

    def render(self) -> np.ndarray | None:
        """rgb_array: (height, width, 3) uint8 frame of the arm at the current joint
        positions with the target marker at the episode's target (after a step that
        collided, the pose it collided in, not the reset pose the env put the arm back
        at: `mara_mjx.viz.render.pose_reached`). human: update the viewer, return None. No
        render_mode: None."""
        if self.render_mode is None:
            return None
        if self.state is None:
            raise gymnasium.error.ResetNeeded("call reset() before render()")
        from mara_mjx.viz.render import pose_reached

        s = self.state
        q, obs, collided, terminated, target_pos, target_quat = jax.device_get(
            (s.q, s.obs, s.metrics["collided"], s.terminated)
            + (s.params.target_pos, s.params.target_quat)
        )
        q = pose_reached(q, obs, collided, terminated)  # not the post-collision reset pose
        if self.render_mode == "rgb_array":
            if self._renderer is None:  # after close()
                from mara_mjx.viz.render import ArmRenderer

                self._renderer = ArmRenderer(*self._render_args)
            return self._renderer.frame(q, target_pos, target_quat)
        if self._viewer is None:
            from mara_mjx.viz.render import Viewer

            self._viewer = Viewer()
        self._viewer.show(q, target_pos, target_quat)
        return None

    def close(self) -> None:
        """Free the renderer or close the viewer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None


def _numpy_info(metrics: dict[str, Any]) -> dict[str, np.ndarray]:
    return {k: np.array(v) for k, v in metrics.items()}


def register_gym_id(task: str) -> str:
    """Register `mara_mjx/<task>-v0` with gymnasium for a name of `mara_mjx.registered()`
    (idempotent; builds nothing). Returns the id."""
    env_id = gym_id(task)
    if env_id not in gymnasium.registry:
        gymnasium.register(
            id=env_id,
            entry_point="mara_mjx.adapters.gym:MaraGymEnv",
            vector_entry_point="mara_mjx.adapters.gym_vector:MaraVectorEnv",
            max_episode_steps=None,
            kwargs={"task": task},
        )
    return env_id


# Every registered env gets an id, the four tasks and any later `mara_mjx.register(name, ...)`.
on_register(register_gym_id)
