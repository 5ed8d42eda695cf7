"""mara_mjx: the gym-gazebo2 MARA arm tasks on MuJoCo MJX.

Public API:
    make(name, **overrides)   build one of `registered()` (MARA, MARAOrient,
                              MARACollision, MARACollisionOrient, and their
                              random-target variants MARARandomTarget, ...)
    register(name, factory)   add your own variant
    Env.reset(key, params=None) -> EnvState;  Env.step(state, action) -> EnvState
    BatchedEnv(env, n)        vmap + auto-reset + episode statistics
    EnvConfig / EnvParams / EnvState / RewardParams

Importing mara_mjx adds one CPU-only flag to XLA_FLAGS (mara_mjx/_xla.py): batched env
steps run about 50x faster on the CPU with XLA's older CPU fusion emitters.
"""

import mara_mjx._xla  # noqa: F401  (first: XLA_FLAGS before anything can start JAX)
import mara_mjx.gym  # noqa: F401  (registers the gymnasium ids mara_mjx/<task>-v0)
from mara_mjx.envs import (
    BatchedEnv,
    BatchedState,
    EnvConfig,
    EnvParams,
    EnvState,
    MaraEnv,
    make,
    register,
    registered,
)
from mara_mjx.rewards import RewardParams

Env = MaraEnv

__all__ = [
    "BatchedEnv",
    "BatchedState",
    "Env",
    "EnvConfig",
    "EnvParams",
    "EnvState",
    "MaraEnv",
    "RewardParams",
    "make",
    "register",
    "registered",
]
__version__ = "0.1.0"
