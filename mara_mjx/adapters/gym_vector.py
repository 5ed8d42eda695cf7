"""The vector half of the gymnasium adapter: `MaraVectorEnv`, N arms in one jitted
`mara_mjx.BatchedEnv` call per step, with gymnasium's NEXT_STEP (default) or SAME_STEP
autoreset (see `mara_mjx.adapters.gym`'s docstring for both, and for the ids:
`gymnasium.make_vec("mara_mjx/MARA-v0", num_envs=N, vectorization_mode="vector_entry_point")`
builds one).
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from mara_mjx.adapters.gym import _check_render_mode, _numpy_info, _spaces, check_action
from mara_mjx.envs import BatchedEnv, make

AUTORESET_MODES = {"next_step": AutoresetMode.NEXT_STEP, "same_step": AutoresetMode.SAME_STEP}


def _autoreset_mode(mode: Any) -> AutoresetMode:
    """An AutoresetMode from itself or its name ("next_step", "same_step")."""
    if isinstance(mode, AutoresetMode) and mode in AUTORESET_MODES.values():
        return mode
    if isinstance(mode, str) and mode.lower() in AUTORESET_MODES:
        return AUTORESET_MODES[mode.lower()]
    raise ValueError(
        f"autoreset_mode={mode!r} is not supported; choose one of {sorted(AUTORESET_MODES)} "
        "(or gymnasium's AutoresetMode.NEXT_STEP / SAME_STEP)"
    )


class MaraVectorEnv(VectorEnv):
    """`num_envs` copies of one MARA task, batched on the device by `mara_mjx.BatchedEnv`.

    Observations (N, obs_size) float32, rewards (N,) float32, terminations/truncations
    (N,) bool; infos hold the metrics (N, ...) of the observation returned, each with a
    `_name` mask. Autoreset modes (see the module docstring): "next_step" (default,
    gymnasium's own and what its vector wrappers, CleanRL and SB3 expect) or
    "same_step".

    Args:
      task: a name of `mara_mjx.registered()`.
      num_envs: N.
      autoreset_mode: "next_step" or "same_step" (or a gymnasium `AutoresetMode`).
      reset_strategy: `BatchedEnv`'s ("select" or "cond").
      devices: `BatchedEnv`'s: devices to spread the N envs over (None: all; N must be a
        multiple of their count; 1: one device).
      render_mode: must be None (to watch an arm, use `MaraGymEnv(render_mode=...)`).
      **overrides: env options of `mara_mjx.make`.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        task: str = "MARA",
        num_envs: int = 1,
        reset_strategy: str = "select",
        render_mode: str | None = None,
        devices: int | None = None,
        autoreset_mode: str | AutoresetMode = "next_step",
        **overrides: Any,
    ):
        _check_render_mode(render_mode, (), "MaraVectorEnv (watch one arm with MaraGymEnv)")
        mode = _autoreset_mode(autoreset_mode)
        self.env = make(task, **overrides)
        self.batched = BatchedEnv(self.env, num_envs, reset_strategy, devices)
        self.task = task
        self.num_envs = num_envs
        self.render_mode = None
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.single_observation_space, self.single_action_space = _spaces(self.env)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._jit_reset = jax.jit(self.batched.reset)
        self._jit_step = jax.jit(functools.partial(_vector_step, self.batched, mode))
        self.state = None  # mara_mjx.BatchedState after reset
        self._held = np.zeros(num_envs, bool)  # NEXT_STEP: ended last step, reset this one

    @property
    def autoreset_mode(self) -> AutoresetMode:
        return self.metadata["autoreset_mode"]

    def precompile(self) -> MaraVectorEnv:
        """Compile the batched reset and step now. The episodes are untouched. Returns self."""
        state = self._jit_reset(jax.random.key(0), self.env.default_params)
        action = np.zeros(self.action_space.shape, np.float32)
        jax.block_until_ready(self._jit_step(state, action, np.zeros(self.num_envs, bool)))
        return self

    def reset(
        self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset all N envs. `seed`: one int (the N keys are split from
        `jax.random.key(seed)`) or a list of N ints (env i starts from
        `jax.random.key(seed[i])`); `options`: params overrides shared by all envs (see
        `MaraEnv.make_params`)."""
        key = self._reset_key(seed)
        params = self.env.make_params(**options) if options else self.env.default_params
        self.state = self._jit_reset(key, params)
        self._held = np.zeros(self.num_envs, bool)
        obs, metrics = jax.device_get((self.state.obs, self.state.metrics))
        return np.array(obs, np.float32), self._infos(_numpy_info(metrics), None)

    def _reset_key(self, seed: Any) -> jax.Array:
        """One key (split into N by BatchedEnv) or N keys, and gymnasium's np_random."""

        def is_int(x: Any) -> bool:
            return isinstance(x, int | np.integer) and not isinstance(x, bool) and x >= 0

        if seed is None or is_int(seed):
            super().reset(seed=None if seed is None else int(seed))
            value = int(self.np_random.integers(2**31)) if seed is None else int(seed)
            return jax.random.key(value)
        if isinstance(seed, list | tuple | np.ndarray) and all(is_int(s) for s in seed):
            if len(seed) != self.num_envs:
                raise ValueError(
                    f"seed has {len(seed)} entries; give one int or a list of num_envs = "
                    f"{self.num_envs} ints"
                )
            super().reset(seed=int(seed[0]))
            return jnp.stack([jax.random.key(int(s)) for s in seed])
        raise ValueError(
            f"seed must be None, one int >= 0 (the {self.num_envs} env keys are split from it) "
            f"or a list of {self.num_envs} ints >= 0, got {seed!r}"
        )

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step all envs with `actions` (N, 6) rad. NEXT_STEP: an env whose episode ended
        at the previous call ignores its action and returns its new episode's first
        observation (reward 0). SAME_STEP: ended episodes reset within this call."""
        if self.state is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        actions = check_action(actions, self.action_space.shape)
        self.state, view = self._jit_step(self.state, actions, self._held)
        view = jax.device_get(view)
        done = np.asarray(view["terminated"] | view["truncated"], bool)
        infos = self._infos(_numpy_info(view["info"]), None)
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            self._held = done
        elif done.any():
            final = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(done):
                final[i] = np.array(view["final_obs"][i], np.float32)
            infos["final_obs"], infos["_final_obs"] = final, done.copy()
            infos["final_info"] = self._infos(_numpy_info(view["final_info"]), done)
            infos["_final_info"] = done.copy()
        return (
            np.array(view["obs"], np.float32),
            np.array(view["reward"], np.float32),
            np.array(view["terminated"], bool),
            np.array(view["truncated"], bool),
            infos,
        )

    def render(self) -> None:
        """Rendering is not supported by this adapter: returns None."""
        return None

    def _infos(self, values: dict[str, Any], mask: np.ndarray | None) -> dict[str, Any]:
        """gymnasium's vector info layout: each key with a `_key` boolean mask."""
        mask = np.ones(self.num_envs, bool) if mask is None else mask
        out: dict[str, Any] = {}
        for name, value in values.items():
            out[name] = value
            out[f"_{name}"] = mask.copy()
        return out


def _vector_step(
    batched: BatchedEnv, mode: AutoresetMode, state: Any, actions: jax.Array, held: jax.Array
) -> tuple[Any, dict[str, Any]]:
    """One jitted vector step: the next BatchedState and what the host returns.

    `BatchedEnv.step` always resets ended episodes within the step (SAME_STEP). NEXT_STEP
    is built on it: the step that ends an episode returns its final observation and
    metrics, and at the next call the envs `held` (N,) bool keep the fresh episode's
    first state instead of stepping, returning its observation with reward 0.
    """
    new = batched.step(state, actions)
    if mode == AutoresetMode.SAME_STEP:
        view = {
            "obs": new.obs,
            "reward": new.reward,
            "terminated": new.terminated,
            "truncated": new.truncated,
            "info": new.env_state.metrics,  # of `obs`: the new episode's where one ended
            "final_obs": new.final_obs,
            "final_info": new.metrics,  # of the step that ended the episode
        }
        return new, view

    def pick(mask, a, b):
        return jax.tree.map(
            lambda x, y: jnp.where(mask.reshape(mask.shape + (1,) * (x.ndim - 1)), x, y), a, b
        )

    done = new.terminated | new.truncated
    env_state = pick(held, state.env_state, new.env_state)
    not_held = ~held
    view = {
        "obs": pick(held, state.env_state.obs, pick(done, new.final_obs, new.obs)),
        "reward": jnp.where(held, 0.0, new.reward),
        "terminated": new.terminated & not_held,
        "truncated": new.truncated & not_held,
        "info": pick(held, state.env_state.metrics, new.metrics),
    }
    return new.replace(env_state=env_state, obs=env_state.obs), view
