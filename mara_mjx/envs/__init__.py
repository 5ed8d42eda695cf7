"""Environments: the `Env` contract (base.py), the MARA arm on MJX (arm.py), the four
tasks (mara.py) and their random-target variants (random_target.py, targets.py), domain
randomisation (randomize.py), the registry and the batching/auto-reset layer (batched.py)."""

from mara_mjx.envs.base import Env, EnvConfig, EnvParams, EnvState, EnvStateLike
from mara_mjx.envs.batched import BatchedEnv, BatchedState
from mara_mjx.envs.mara import TASKS, MaraEnv, Task
from mara_mjx.envs.random_target import RANDOM_TASKS, RandomTargetEnv, RandomTargetParams
from mara_mjx.envs.registry import make, register, registered

__all__ = [
    "RANDOM_TASKS",
    "TASKS",
    "BatchedEnv",
    "BatchedState",
    "Env",
    "EnvConfig",
    "EnvParams",
    "EnvState",
    "EnvStateLike",
    "MaraEnv",
    "RandomTargetEnv",
    "RandomTargetParams",
    "Task",
    "make",
    "register",
    "registered",
]
