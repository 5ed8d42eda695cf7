"""Environments spread over devices: one mesh axis, "envs", and nothing else.

    mesh = make_mesh()            # every device (all hosts after jax.distributed.initialize)
    mesh = make_mesh(2)           # the first two devices
    x = constrain(x, mesh, axis=1)   # inside jit: shard axis 1 of every leaf over "envs"
    f = map_envs(f, mesh, in_axes=(None, 1), out_axes=None)   # f per device, on its shard

Data parallelism. The batched env state and the rollout are sharded along their
environment axis the GSPMD way (`constrain`: the single-device program plus annotations;
XLA partitions it). PPO's SGD phase is written per device instead (`map_envs`, i.e.
`jax.shard_map`): each device shuffles and splits *its own* environments' samples, so no
sample crosses devices, and the only collectives are the ones written out with `pmean`:
one gradient all-reduce per minibatch (of one flat buffer) and the per-minibatch
advantage statistics once per epoch (benchmarks/NOTES.md section 10 says why).
Parameters and optimiser state are replicated and every device applies the same update.
The split of samples into minibatches depends only on global environment indices, so N
devices compute what one device computes on the same global batch, up to the order of
floating-point reductions.
JAX's random numbers are partitionable (the default `jax_threefry_partitionable`), so the
same key gives the same numbers however the arrays are sharded.

With one device `make_mesh` returns None, `constrain` and `pmean` are the identity and
`map_envs(f)` is `f`: the single-device program has no annotations at all.

Several processes (hosts): after `jax.distributed.initialize()` in every process (the
train CLI does it, mara_mjx.runtime.distributed), `jax.devices()` lists every process's devices
and the same code runs everywhere, each process stepping its own devices' share of the
environments. A jitted function must not close over an array on another process's
device: MJX's default device, `jax.devices()[0]`, is process 0's, so the arm's model is
put on `jax.local_devices()[0]` (mara_mjx.envs.arm).
"""

from __future__ import annotations

from collections.abc import Callable
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


def map_envs(
    f: Callable[..., Any], mesh: Mesh | None, in_axes: tuple[int | None, ...], out_axes: Any
) -> Callable[..., Any]:
    """`f` run once per device on its shard (`jax.shard_map`); `f` itself when mesh is None.

    in_axes: per argument, the axis sharded over "envs" (None: replicated, the same on
    every device). out_axes: the same for the outputs (a prefix of their tree). Inside
    `f`, arrays have their per-device shape, and `pmean(x, mesh)` averages over devices.

    The only collectives are the ones `f` writes: with `check_vma=False`, a gradient
    with respect to a replicated input is this device's gradient, to be `pmean`-ed (with
    JAX's default check_vma=True it would come back already summed over devices). A
    replicated output must be the same on every device; `f` guarantees that.
    """
    if mesh is None:
        return f

    def specs(axes):
        return PartitionSpec() if axes is None else spec(axes)

    out_specs = jax.tree.map(specs, out_axes, is_leaf=lambda x: x is None)
    return jax.shard_map(
        f,
        mesh=mesh,
        in_specs=tuple(specs(a) for a in in_axes),
        out_specs=out_specs,
        check_vma=False,
    )


def pmean(tree: Any, mesh: Mesh | None) -> Any:
    """Mean over the devices of `mesh`, inside `map_envs`; identity when mesh is None."""
    return tree if mesh is None else jax.lax.pmean(tree, AXIS)


def put(tree: Any, mesh: Mesh | None, axis: int | None = None) -> Any:
    """Every array leaf of `tree` placed on the mesh (outside jit): dimension `axis`
    sharded over "envs", or replicated (None); `tree` itself when mesh is None. With
    several processes, every process must pass the same values (e.g. read from the same
    checkpoint): each keeps its devices' part."""
    if mesh is None:
        return tree
    target = NamedSharding(mesh, PartitionSpec() if axis is None else spec(axis))
    # jit rather than device_put: its outputs carry the mesh in their type as those of
    # the training program do (device_put's replicated ones do not: a new compile)
    return jax.jit(lambda t: t, out_shardings=target)(tree)


def replicate(tree: Any, mesh: Mesh | None) -> Any:
    """Every array leaf of `tree` replicated on the mesh (inside jit)."""
    if mesh is None:
        return tree
    sharding = NamedSharding(mesh, PartitionSpec())
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, sharding), tree)
