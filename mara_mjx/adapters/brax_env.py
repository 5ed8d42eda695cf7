"""A mara_mjx env as a brax environment, so brax's PPO can train on it.

    from mara_mjx.adapters.brax_env import make_brax_env   # first: JAX shim, quiet mujoco.mjx
    from brax.training.agents.ppo import train as ppo

    env = make_brax_env("MARACollision")          # a brax.envs.base.Env
    make_inference_fn, params, metrics = ppo.train(
        environment=env, episode_length=env.episode_length, num_timesteps=...,
        num_envs=..., batch_size=..., num_evals=...)   # brax's evaluator included

Tested with brax 0.14.2 (the `brax` extra) and JAX 0.10 (tests/test_brax_train.py runs
brax's `ppo.train`, evaluator on, on this adapter).

* **JAX compatibility (applied on import).** brax 0.14.2's `ppo.train` calls
  `jax.device_put_replicated`, which JAX 0.10 removed (accessing it raises
  "jax.device_put_replicated is deprecated"; google/brax#671). Importing this module
  gives `jax` JAX's documented drop-in replacement (`device_put_replicated` below,
  docs.jax.dev migrate_pmap.html#drop-in-replacements) where JAX has none, for the whole
  process; a JAX that still has its own keeps it.

Choices (documented here because they differ from mara_mjx's own PPO and batching):

* **Actions.** brax's PPO samples tanh-squashed actions in [-1, 1]. The adapter maps
  them affinely to the joint box: q_cmd = lower + (a + 1) / 2 (upper - lower) rad,
  after clipping a to [-1, 1]. mara_mjx's own PPO passes raw joint targets (rad).
  Non-finite entries stay non-finite and the mara env holds the joint (as it does for
  raw actions).
* **Time limit.** brax's `EpisodeWrapper` (`brax.envs.wrappers.training.wrap`) owns
  the horizon: it counts `info['steps']`, sets `done` at `episode_length` and
  `info['truncation'] = 1` there, which brax's GAE uses to bootstrap. If the mara env
  also truncated, `EpisodeWrapper` would see `done` already set and report
  truncation 0 (no bootstrap), so the adapter builds the mara env with a horizon it
  never reaches (`max_episode_steps = 2**30 - 1`) and `make_brax_env` refuses a
  `max_episode_steps` option: pass `episode_length` to `wrap` / `ppo.train` instead
  (`env.episode_length` is the paper's 1024). `State.done` is then the mara
  `terminated | truncated` as float32, in practice the physics blow-up only.
* **State.** The mara `EnvState` is `State.pipeline_state`; `step` delegates to
  `MaraEnv.step`. brax's `AutoResetWrapper` resets by restoring the first
  `pipeline_state` of each env (cached at `reset`, including its PRNG key), so with
  `reset_noise > 0` every episode of one env starts from the same perturbed pose;
  with the training default `reset_noise = 0` the reset pose is the same anyway.
* **Metrics.** brax's `EpisodeWrapper` sums every `State.metrics` entry over the
  episode into arrays of shape (N,), so metrics must be scalars per env. The adapter
  reports the per-step quantities only (the mara running totals would be summed
  twice): see `METRICS`. The keys are fixed from reset on: `step` keeps every key of
  the state it is given (brax's `EvalWrapper` adds `reward` to the reset state's
  metrics, and the loops of brax's wrappers and evaluator need the same keys in and
  out), updating the adapter's own.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.envs.arm import _mjx

try:
    _mjx()  # brax imports mujoco.mjx: first arm's quiet import (no "Failed to import warp")
    from brax.envs.base import Env, State
except ImportError as e:  # brax is an optional extra
    if (getattr(e, "name", None) or "brax").split(".")[0] != "brax":
        raise  # not brax itself (mujoco.mjx, say): its own error
    raise ImportError(
        "mara_mjx.adapters.brax_env needs brax: pip install 'mara_mjx[brax]' (or brax==0.14.2)"
    ) from e

import mara_mjx


def device_put_replicated(x: Any, devices: list[jax.Device]) -> Any:
    """JAX's drop-in replacement for the removed `jax.device_put_replicated`: every leaf
    of `x` stacked `len(devices)` times along a new leading axis, that axis sharded over
    `devices` (one copy per device)."""
    mesh = jax.sharding.Mesh(np.array(devices), ("x",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("x"))
    return jax.tree.map(lambda y: jax.device_put(jnp.stack([y] * len(devices)), sharding), x)


if "device_put_replicated" not in vars(jax):  # JAX >= 0.10: brax 0.14.2's ppo.train needs it
    jax.device_put_replicated = device_put_replicated

# A horizon the mara env never reaches inside a brax episode (EnvConfig's bound is 2**30).
NEVER = 2**30 - 1

# State.metrics keys, all () float32 per env (per step, summed per episode by brax).
METRICS = (
    "distance",  # m, RMS position error (the reward's d)
    "position_error_x",  # m, |e_x|
    "position_error_y",  # m, |e_y|
    "position_error_z",  # m, |e_z|
    "angle",  # rad, orientation error angle theta
    "orientation_error_roll",  # rad
    "orientation_error_pitch",  # rad
    "orientation_error_yaw",  # rad
    "collided",  # 0/1, this step collided
    "nonfinite_actions",  # number of non-finite action entries in this step
    "physics_blowup",  # 0/1, the physics state went non-finite (terminates)
)


class BraxMaraEnv(Env):
    """brax view of one mara_mjx env (see the module docstring for the choices).

    Observation: the mara env's, (12,) or (16,). Action: (6,) in [-1, 1], mapped to the
    joint box. Reward: the mara env's. `pipeline_state`: the mara `EnvState`.
    """

    def __init__(self, env: Any, episode_length: int = 1024):
        if env.max_episode_steps < NEVER:
            raise ValueError(
                f"the mara env truncates at {env.max_episode_steps} steps; build it with "
                f"max_episode_steps={NEVER} (make_brax_env does) and let brax's "
                "EpisodeWrapper own the horizon (episode_length)"
            )
        self.env = env
        self.episode_length = episode_length
        """Horizon (steps) to pass to brax's `wrap` / `ppo.train`; the paper's 1024."""
        self._lower = jnp.asarray(env.joint_lower, jnp.float32)
        self._upper = jnp.asarray(env.joint_upper, jnp.float32)

    # ------------------------------------------------------------- properties
    @property
    def observation_size(self) -> int:
        return int(self.env.observation_size)

    @property
    def action_size(self) -> int:
        return int(self.env.action_size)

    @property
    def backend(self) -> str:
        return "mjx"

    # ------------------------------------------------------------------- API
    def to_joint_targets(self, action: jax.Array) -> jax.Array:
        """(6,) in [-1, 1] -> (6,) rad joint targets (affine onto [lower, upper])."""
        a = jnp.clip(action, -1.0, 1.0)
        return self._lower + (a + 1.0) * 0.5 * (self._upper - self._lower)

    def reset(self, rng: jax.Array) -> State:
        """`rng`: a PRNG key; brax passes raw (2,) uint32 keys, used as they are."""
        es = self.env.reset(rng)
        return State(
            pipeline_state=es,
            obs=es.obs,
            reward=es.reward.astype(jnp.float32),
            done=es.done.astype(jnp.float32),
            metrics=_metrics(es),
            info={},
        )

    def step(self, state: State, action: jax.Array) -> State:
        """One mara step with the action mapped to joint targets."""
        es = self.env.step(state.pipeline_state, self.to_joint_targets(action))
        return state.replace(
            pipeline_state=es,
            obs=es.obs,
            reward=es.reward.astype(jnp.float32),
            done=es.done.astype(jnp.float32),
            metrics={**state.metrics, **_metrics(es)},  # a wrapper's keys stay
        )


def _metrics(es: Any) -> dict[str, jax.Array]:
    m = es.metrics
    pe, oe = m["position_error"], m["orientation_error"]
    out = {
        "distance": m["distance"],
        "position_error_x": pe[0],
        "position_error_y": pe[1],
        "position_error_z": pe[2],
        "angle": m["angle"],
        "orientation_error_roll": oe[0],
        "orientation_error_pitch": oe[1],
        "orientation_error_yaw": oe[2],
        "collided": m["collided"],
        "nonfinite_actions": m["nonfinite_actions"],
        "physics_blowup": m["physics_blowup"],
    }
    return {k: jnp.asarray(out[k], jnp.float32) for k in METRICS}


def make_brax_env(name: str, episode_length: int = 1024, **env_options: Any) -> BraxMaraEnv:
    """A registered mara_mjx env as a brax env. `env_options` are `mara_mjx.make` options
    (driver, velocity, target_pos, ...) except `max_episode_steps`: the horizon is
    brax's `episode_length` (steps), given to `wrap` / `ppo.train`."""
    if "max_episode_steps" in env_options:
        raise ValueError(
            "max_episode_steps is not an option of make_brax_env: brax's EpisodeWrapper owns "
            "the horizon; pass episode_length to brax.envs.training.wrap or ppo.train"
        )
    if (
        not isinstance(episode_length, int)
        or isinstance(episode_length, bool)
        or episode_length < 1
    ):
        raise ValueError(f"episode_length must be a positive int, got {episode_length!r}")
    env = mara_mjx.make(name, max_episode_steps=NEVER, **env_options)
    return BraxMaraEnv(env, episode_length)
