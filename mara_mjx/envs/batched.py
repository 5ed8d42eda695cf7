"""N environments in one state: vmap, auto-reset and episode statistics.

`BatchedEnv.step` steps every environment; those whose episode ended (terminated
or truncated) are reset in the same call, brax-style: the returned `obs` is the
first observation of the new episode, while `final_obs`, `episode_return`,
`episode_length` and `episode_collisions` keep what the ended episode produced, and
`reward`, `terminated`, `truncated` are those of the step that ended it.

Reset strategy: always a fresh `env.reset` with a new key for each ended episode
(never a cached first state replayed forever). Two ways to run it, a named choice
measured by `benchmarks/profile_step.py` (see benchmarks/NOTES.md):
  * "select" (default): compute a reset for every environment each step and pick it
    with `jnp.where(done, ...)`. The MARA reset is kinematics only (about 1/15 of a
    step), and nothing waits on the host.
  * "cond": run the resets under `lax.cond(any(done))`. The tasks truncate all
    environments together, so the branch is rarely taken, but on GPU XLA reads the
    predicate back to the host every step. Which is faster depends on the loop around
    the step (an H100, the fused pass at 262,144 envs: cond 20% ahead in `benchmark
    limit`'s loop, 14% behind in profile_step.py's; benchmarks/NOTES.md section 70).

Devices: `devices=None` (default) spreads the environments over every device
(`mara_mjx.runtime.sharding`): the state is sharded along its leading (N,) axis, so num_envs
must be a multiple of the device count; `devices=1` keeps everything on one device.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from mara_mjx.envs.base import Env, EnvParams, EnvState  # noqa: F401
from mara_mjx.runtime import sharding


@struct.dataclass
class BatchedState:
    """State of N environments. `env_state` leaves have a leading (N,) axis."""

    env_state: EnvState
    obs: jax.Array  # (N, obs) observation to act on (after any auto-reset)
    reward: jax.Array  # (N,)
    terminated: jax.Array  # (N,) bool
    truncated: jax.Array  # (N,) bool
    final_obs: jax.Array  # (N, obs) last observation of the step's episode (pre-reset)
    episode_return: jax.Array  # (N,) return of the episode that ended at this step, else 0
    episode_length: jax.Array  # (N,) its length, else 0
    episode_collisions: jax.Array  # (N,) its collision count, else 0
    metrics: dict[str, jax.Array]  # per-env metrics of this step (pre-reset)

    @property
    def done(self) -> jax.Array:
        return self.terminated | self.truncated


class BatchedEnv:
    """Vectorised, auto-resetting wrapper of one env for `num_envs` environments. `env`:
    anything that follows the `mara_mjx.envs.base.Env` contract."""

    RESET_STRATEGIES = ("select", "cond")

    def __init__(
        self, env: Env, num_envs: int, reset_strategy: str = "select", devices: int | None = None
    ):
        if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
        self.mesh = sharding.make_mesh(devices)
        sharding.check_divisible("num_envs", num_envs, self.mesh)
        if reset_strategy not in self.RESET_STRATEGIES:
            raise ValueError(
                f"reset_strategy={reset_strategy!r} is not valid; choose one of "
                f"{self.RESET_STRATEGIES}"
            )
        self.reset_strategy = reset_strategy
        self.env = env
        self.num_envs = num_envs
        self._reset = jax.vmap(env.reset)
        self._step = jax.vmap(env.step)

    @property
    def observation_size(self) -> int:
        return self.env.observation_size

    @property
    def action_size(self) -> int:
        return self.env.action_size

    def reset(self, key: jax.Array, params: EnvParams | None = None) -> BatchedState:
        """Reset all environments. `key`: one PRNG key (split into N) or N keys, shape
        (N,), one per environment. `params`: None (env defaults), one EnvParams shared
        by all, or an EnvParams with a leading (N,) axis (per-environment values)."""
        typed = jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
        if typed and key.shape == (self.num_envs,):
            keys = key
        elif typed and key.shape != ():
            raise ValueError(
                f"key must be one PRNG key or {self.num_envs} keys, got shape {key.shape}"
            )
        else:  # one typed key, or one raw uint32 key (jax.random.PRNGKey)
            keys = jax.random.split(key, self.num_envs)
        params = self._batch_params(params)
        s = self._reset(keys, params)
        zeros = jnp.zeros(self.num_envs)
        state = BatchedState(
            env_state=s,
            obs=s.obs,
            reward=s.reward,
            terminated=s.terminated,
            truncated=s.truncated,
            final_obs=s.obs,
            episode_return=zeros,
            episode_length=zeros,
            episode_collisions=zeros,
            metrics=s.metrics,
        )
        return sharding.constrain(state, self.mesh)

    def step(self, state: BatchedState, action: jax.Array) -> BatchedState:
        """Step all environments with `action` (N, action_size); auto-reset ended ones."""
        expected = (self.num_envs, self.env.action_size)
        if action.shape != expected:
            raise ValueError(f"action must have shape {expected}, got {action.shape}")
        s = self._step(state.env_state, action)
        done = s.terminated | s.truncated

        def reset_done(s: EnvState) -> EnvState:
            keys = jax.vmap(jax.random.split)(s.key)
            fresh = self._reset(keys[:, 1], s.params)
            fresh = fresh.replace(key=keys[:, 0])
            pick = lambda new, old: jnp.where(  # noqa: E731
                done.reshape(done.shape + (1,) * (new.ndim - 1)), new, old
            )
            return jax.tree.map(pick, fresh, s)

        with jax.named_scope("auto_reset"):
            if self.reset_strategy == "cond":
                new = jax.lax.cond(jnp.any(done), reset_done, lambda s: s, s)
            else:
                new = reset_done(s)
        m = s.metrics
        state = BatchedState(
            env_state=new,
            obs=new.obs,
            reward=s.reward,
            terminated=s.terminated,
            truncated=s.truncated,
            final_obs=s.obs,
            episode_return=jnp.where(done, m["episode_return"], 0.0),
            episode_length=jnp.where(done, m["episode_length"], 0.0),
            episode_collisions=jnp.where(done, m["collisions"], 0.0),
            metrics=m,
        )
        return sharding.constrain(state, self.mesh)

    def _batch_params(self, params):
        """Broadcast unbatched params to (N, ...); check batched ones have N rows."""
        default = self.env.default_params
        params = default if params is None else params
        leaf, ref = jax.tree.leaves(params)[0], jax.tree.leaves(default)[0]
        if jnp.ndim(leaf) == jnp.ndim(ref):
            return jax.tree.map(
                lambda x: jnp.broadcast_to(x, (self.num_envs, *jnp.shape(x))), params
            )
        if jnp.shape(leaf)[0] != self.num_envs:
            raise ValueError(
                f"batched params have {jnp.shape(leaf)[0]} rows, expected {self.num_envs}"
            )
        return params
