"""mara_mjx: the gym-gazebo2 MARA arm tasks on MuJoCo MJX.

Public API:
    make(name, **overrides)   build one of `registered()` (MARA, MARAOrient,
                              MARACollision, MARACollisionOrient, and their
                              random-target variants MARARandomTarget, ...)
    register(name, factory)   add your own variant
    Env                       the contract every consumer relies on (a Protocol):
                              reset(key, params=None) -> state, step(state, action)
                              -> state, observation_size, action_size,
                              max_episode_steps, default_params
    MaraEnv                   the MARA tasks' implementation of it
    BatchedEnv(env, n)        vmap + auto-reset + episode statistics
    EnvConfig / EnvParams / EnvState / RewardParams
    RandomizeConfig           domain randomisation ranges (make(name, randomize=True))

Importing mara_mjx adds one CPU-only flag to XLA_FLAGS (mara_mjx/_xla.py): batched env
steps run about 50x faster on the CPU with XLA's older CPU fusion emitters.
"""

import mara_mjx._xla  # noqa: F401  (first: XLA_FLAGS before anything can start JAX)
import mara_mjx.adapters.gym  # noqa: F401  (registers the gymnasium ids mara_mjx/<task>-v0)
from mara_mjx.envs import (
    BatchedEnv,
    BatchedState,
    Env,
    EnvConfig,
    EnvParams,
    EnvState,
    EnvStateLike,
    MaraEnv,
    make,
    register,
    registered,
)
from mara_mjx.envs.randomize import RandomizeConfig
from mara_mjx.envs.rewards import RewardParams

__all__ = [
    "BatchedEnv",
    "BatchedState",
    "Env",
    "EnvConfig",
    "EnvParams",
    "EnvState",
    "EnvStateLike",
    "MaraEnv",
    "RandomizeConfig",
    "RewardParams",
    "make",
    "register",
    "registered",
]
__version__ = "0.1.0"
