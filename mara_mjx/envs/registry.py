"""An open registry of environments: name -> factory(**overrides) -> env.

mara_mjx.make("MARACollisionOrient", driver="real", velocity=0.3)
mara_mjx.register("MyMARA", lambda **kw: MaraEnv(my_task, my_config.replace(**kw)))
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from mara_mjx.envs.mara import TASKS, MaraEnv, Task, default_config
from mara_mjx.envs.random_target import RANDOM_TASKS, RandomTargetEnv, random_target_config

_REGISTRY: dict[str, Callable[..., Any]] = {}
# Called with each newly registered name (the gymnasium adapter registers an id), so that
# nothing on this floor imports the adapters above it.
_LISTENERS: list[Callable[[str], None]] = []


def on_register(listener: Callable[[str], None]) -> None:
    """Call `listener(name)` for every registered name, now and at each later `register`."""
    _LISTENERS.append(listener)
    for name in _REGISTRY:
        listener(name)


def register(name: str, factory: Callable[..., Any], *, overwrite: bool = False) -> None:
    """Register `factory(**overrides)` under `name` for `make`."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"env name must be a non-empty string, got {name!r}")
    if not callable(factory):
        raise TypeError(f"factory for {name!r} must be callable, got {type(factory).__name__}")
    if name in _REGISTRY and not overwrite:
        raise ValueError(f"env {name!r} is already registered; pass overwrite=True to replace it")
    _REGISTRY[name] = factory
    for listener in _LISTENERS:
        listener(name)


def registered() -> tuple[str, ...]:
    """Names `make` accepts."""
    return tuple(_REGISTRY)


def make(name: str, **overrides: Any) -> Any:
    """Build a registered env. Overrides are fields of `mara_mjx.EnvConfig` (driver,
    max_episode_steps, control_dt, velocity, target_pos, target_quat, alpha, beta,
    gamma, delta, eta, done, reward, check_target; for the random-target tasks also
    target_min, target_max, target_spread_deg, target_table_size, target_seed)."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown env {name!r}; registered envs are {list(_REGISTRY)}")
    return _REGISTRY[name](**overrides)


def _task_factory(task: Task) -> Callable[..., MaraEnv]:
    def factory(**overrides: Any) -> MaraEnv:
        return MaraEnv(task, default_config(task).replace(**overrides))

    factory.__doc__ = f"The {task.name} task. Overrides: EnvConfig fields."
    return factory


def _random_task_factory(task: Task) -> Callable[..., RandomTargetEnv]:
    def factory(**overrides: Any) -> RandomTargetEnv:
        return RandomTargetEnv(task, random_target_config(task).replace(**overrides))

    factory.__doc__ = f"The {task.name} task (a new target every episode). Overrides: EnvConfig."
    return factory


for _task in TASKS.values():
    register(_task.name, _task_factory(_task))
for _task in RANDOM_TASKS.values():
    register(_task.name, _random_task_factory(_task))
