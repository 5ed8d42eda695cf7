"""Environments spread over devices: one mesh axis, "envs", and nothing else.

    mesh = make_mesh()            # every device (all hosts after jax.distributed.initialize)
    mesh = make_mesh(2)           # the first two devices
    x = constrain(x, mesh, axis=1)   # inside jit: shard axis 1 of every leaf over "envs"

Data parallelism the GSPMD way: the batched env state, the rollout and the minibatches
are sharded along their environment axis; the parameters and optimiser state are
replicated; the loss is a mean over the whole (sharded) minibatch, so XLA inserts the
all-reduce that averages the gradients across devices and every device applies the same
update. The program is the single-device one with sharding annotations, so N devices
compute what one device computes on the same global batch, up to the order of
floating-point reductions. JAX's random numbers are partitionable (the default
`jax_threefry_partitionable`), so the same key gives the same numbers however the
arrays are sharded.

With one device `make_mesh` returns None and `constrain` is the identity: the
single-device program has no annotations at all.

Several hosts: call `jax.distributed.initialize()` first in every process (see the
README); `jax.devices()` then lists every host's devices and the same code runs
everywhere, each process stepping its own hosts' share of the environments.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "envs"


def device_count(devices: int | None = None) -> int:
    """Validated number of devices: None or 0 -> all (`jax.device_count()`)."""
    available = jax.device_count()
    if devices is None or devices == 0:
        return available
    if not isinstance(devices, int) or isinstance(devices, bool) or devices < 0:
        raise ValueError(f"devices must be an int >= 0 (0 = all), got {devices!r}")
    if devices > available:
        raise ValueError(
            f"devices={devices} but only {available} {jax.default_backend()} device(s) are "
            f"available; choose 1..{available} (0 = all)"
        )
    return devices


def make_mesh(devices: int | None = None) -> Mesh | None:
    """A 1-D mesh ("envs") over the first `devices` devices; None for a single device."""
    n = device_count(devices)
    if n == 1:
        return None
    return Mesh(np.asarray(jax.devices()[:n]), (AXIS,))


def check_divisible(what: str, size: int, mesh: Mesh | None) -> None:
    """A clear error when `size` (envs, minibatch rows) cannot be split over the mesh."""
    n = 1 if mesh is None else mesh.size
    if size % n:
        raise ValueError(
            f"{what}={size} is not divisible by the {n} devices in use; choose a multiple of "
            f"{n} (e.g. {size + n - size % n}) or fewer devices (--devices)"
        )


def spec(axis: int) -> PartitionSpec:
    """Shard dimension `axis` over "envs", replicate the others."""
    return PartitionSpec(*([None] * axis), AXIS)


def constrain(tree: Any, mesh: Mesh | None, axis: int = 0) -> Any:
    """Every array leaf of `tree` sharded along `axis` (inside jit); identity when
    mesh is None."""
    if mesh is None:
        return tree
    sharding = NamedSharding(mesh, spec(axis))
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, sharding), tree)


def replicate(tree: Any, mesh: Mesh | None) -> Any:
    """Every array leaf of `tree` replicated on the mesh (inside jit)."""
    if mesh is None:
        return tree
    sharding = NamedSharding(mesh, PartitionSpec())
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, sharding), tree)
