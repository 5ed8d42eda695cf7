"""The dataclass-config machinery shared by every config: PPO's, the run's, the
evaluation's (`mara_mjx.ppo.config`), the env's (`mara_mjx.envs.base.EnvConfig`) and the
benchmark studies' (`mara_mjx.bench`).

Configs are frozen dataclasses with a docstring under each field (read by `field_docs`
for the generated command-line help, `mara_mjx.cli.common`), validated in `__post_init__`
with the `check_*` helpers, whose errors name the field and the valid values.
Imports nothing from mara_mjx, so any floor may use it.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import math
import textwrap
from typing import Any, TypeVar

import numpy as np

C = TypeVar("C")


class ConfigMixin:
    """to_dict / from_dict / replace shared by the config dataclasses."""

    def to_dict(self) -> dict[str, Any]:
        return {f.name: plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls: type[C], data: dict[str, Any]) -> C:
        """Build from `to_dict()` output (JSON lists become tuples); unknown keys raise."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(
                f"unknown {cls.__name__} field(s) {unknown}; valid fields are {sorted(names)}"
            )
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})

    def replace(self: C, **overrides: Any) -> C:
        """A new config with `overrides` applied (and validated); unknown names raise."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise ValueError(
                f"unknown {type(self).__name__} field(s) {unknown}; valid fields are "
                f"{sorted(names)}"
            )
        return dataclasses.replace(self, **overrides)


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """{field name: its docstring, whitespace collapsed} of a dataclass and its dataclass
    bases, read from their source; {} where the source is unavailable."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if dataclasses.is_dataclass(klass):
            docs.update(_own_field_docs(klass))
    return docs


def _own_field_docs(cls: type) -> dict[str, str]:
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):
        return {}
    body = tree.body[0].body
    docs = {}
    for node, after in zip(body, body[1:], strict=False):
        is_field = isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
        is_doc = isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
        if is_field and is_doc and isinstance(after.value.value, str):
            docs[node.target.id] = " ".join(after.value.value.split())
    return docs


def plain(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


def is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def check_int(name: str, value: Any, minimum: int) -> None:
    if not is_int(value) or value < minimum:
        raise ValueError(f"{name} must be an int >= {minimum}, got {value!r}")


def check_range(name: str, value: Any, low: float, high: float, low_open: bool = False) -> None:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    ok = ok and (value > low if low_open else value >= low) and value <= high
    if not ok:
        bracket = "(" if low_open else "["
        raise ValueError(f"{name}={value!r} must be a finite number in {bracket}{low}, {high}]")


def is_finite(x: Any) -> bool:
    """A number (or numeric string) that is finite."""
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def check_vector(name: str, value: Any, size: int) -> None:
    """ValueError unless `value` is `size` finite numbers."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be {size} numbers, got {value!r}") from e
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}={arr.tolist()} must be finite")
