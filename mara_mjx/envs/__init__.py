"""Environments: the MARA arm on MJX, the four tasks, the registry and batching."""

from mara_mjx.envs.base import EnvConfig, EnvParams, EnvState
from mara_mjx.envs.batched import BatchedEnv, BatchedState
from mara_mjx.envs.mara import TASKS, MaraEnv, Task
from mara_mjx.envs.registry import make, register, registered

__all__ = [
    "TASKS",
    "BatchedEnv",
    "BatchedState",
    "EnvConfig",
    "EnvParams",
    "EnvState",
    "MaraEnv",
    "Task",
    "make",
    "register",
    "registered",
]
