"""Environments: the MARA arm on MJX, the four tasks and their random-target variants, the
registry and batching."""

from mara_mjx.envs.base import EnvConfig, EnvParams, EnvState
from mara_mjx.envs.batched import BatchedEnv, BatchedState
from mara_mjx.envs.mara import TASKS, MaraEnv, Task
from mara_mjx.envs.random_target import RANDOM_TASKS, RandomTargetEnv, RandomTargetParams
from mara_mjx.envs.registry import make, register, registered

__all__ = [
    "RANDOM_TASKS",
    "TASKS",
    "BatchedEnv",
    "BatchedState",
    "EnvConfig",
    "EnvParams",
    "EnvState",
    "MaraEnv",
    "RandomTargetEnv",
    "RandomTargetParams",
    "Task",
    "make",
    "register",
    "registered",
]
