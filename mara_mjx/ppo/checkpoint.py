"""Checkpoint I/O: one .npz file per checkpoint, written atomically, and finding them.

A checkpoint holds every leaf of the `RunnerState` (params, optimiser state, observation
statistics, the state of every env, the PRNG key, the update count) under a readable
name such as `params/params/actor/Dense_0/kernel`, plus a JSON `__meta__` entry with the
resolved config (env name and env config, ppo, policy, curriculum, run, eval; one
written before the PPOConfig split, with every field flat under ppo, is converted on
loading: `mara_mjx.ppo.config.upgrade_meta`), the host progress (update,
env steps as Python ints, wall-clock time, time-to-accuracy records), the versions of
python/jax/mujoco/flax/optax/numpy and the git commit when available. PRNG keys are
stored as their raw uint32 key data.

Writes go to a temporary file in the same folder, then `os.replace`, so a crash never
leaves a half-written checkpoint under the final name; a checkpoint damaged anyway is
skipped, with a warning, by `find_checkpoint` on a run folder.

Naming: <run folder>/checkpoints/ckpt_<update:08d>.npz. Loading a policy from a
checkpoint is `mara_mjx.ppo.policy`'s; run folders (provenance, pruning, the env of a
run) are `mara_mjx.runtime.runs`'.
"""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.runtime import files
from mara_mjx.runtime.npzmeta import META_KEY, NPZ_ERRORS, read_npz_with_meta

FORMAT = "mara_mjx.ppo.checkpoint/1"
CHECKPOINT_DIR = "checkpoints"
_NAME = re.compile(r"^ckpt_(\d+)\.npz$")


class CheckpointError(ValueError):
    """A missing, unreadable, corrupt or mismatching checkpoint (a user error)."""


def checkpoint_name(update: int) -> str:
    return f"ckpt_{update:08d}.npz"


def leaf_name(path: tuple[Any, ...]) -> str:
    """'params/params/actor/Dense_0/kernel' from a jax key path."""
    parts = []
    for k in path:
        for attr in ("name", "key", "idx"):
            if hasattr(k, attr):
                parts.append(str(getattr(k, attr)))
                break
        else:
            parts.append(str(k))
    return "/".join(parts)


def _is_key(x: Any) -> bool:
    return hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jax.dtypes.prng_key)


def state_to_arrays(state: Any) -> dict[str, np.ndarray]:
    """Named numpy arrays of every leaf (PRNG keys as key data)."""
    leaves, _ = jax.tree_util.tree_flatten_with_path(state)
    arrays = {}
    for path, leaf in leaves:
        value = jax.random.key_data(leaf) if _is_key(leaf) else leaf
        if isinstance(value, jax.Array) and not value.is_fully_addressable:
            # sharded over several hosts (jax.distributed): every process gets it all
            from jax.experimental import multihost_utils

            value = multihost_utils.process_allgather(value, tiled=True)
        arrays[leaf_name(path)] = np.asarray(jax.device_get(value))
    return arrays


def arrays_to_state(arrays: dict[str, np.ndarray], template: Any, prefix: str = "") -> Any:
    """The pytree `template` (arrays or ShapeDtypeStructs) filled from `arrays`; a
    missing leaf or a shape/dtype mismatch raises CheckpointError naming the leaf."""
    leaves, treedef = jax.tree_util.tree_flatten_with_path(template)
    out = []
    for path, ref in leaves:
        name = prefix + leaf_name(path)
        if name not in arrays:
            raise CheckpointError(
                f"checkpoint has no array {name!r}; it was written by another config or version"
            )
        value = arrays[name]
        if _is_key(ref):
            impl = jax.random.key_impl(ref) if isinstance(ref, jax.Array) else None
            expected = jax.eval_shape(lambda r: jax.random.key_data(r), ref)
            if value.shape != expected.shape or value.dtype != expected.dtype:
                raise CheckpointError(_mismatch(name, value, expected))
            out.append(jax.random.wrap_key_data(jnp.asarray(value), impl=impl))
            continue
        if value.shape != tuple(ref.shape) or value.dtype != ref.dtype:
            raise CheckpointError(_mismatch(name, value, ref))
        out.append(jnp.asarray(value))
    return jax.tree_util.tree_unflatten(treedef, out)


def _mismatch(name: str, value: np.ndarray, ref: Any) -> str:
    return (
        f"checkpoint array {name!r} has shape {value.shape} {value.dtype}, but this config "
        f"needs {tuple(ref.shape)} {ref.dtype}"
    )


def save_checkpoint(path: str | os.PathLike, state: Any, meta: dict[str, Any]) -> Path:
    """Write `state` and `meta` to `path` (.npz) atomically."""
    arrays = state_to_arrays(state)
    meta = {"format": FORMAT, **meta}
    arrays[META_KEY] = np.array(json.dumps(meta))
    return files.write_atomic(path, lambda f: np.savez(f, **arrays), durable=True)


def load_checkpoint(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """(arrays, meta) of a checkpoint file; CheckpointError if missing or corrupt."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {str(path)!r} does not exist (or is not a file)")
    try:
        arrays, meta = read_npz_with_meta(path)
    except NPZ_ERRORS as e:
        raise CheckpointError(
            f"checkpoint {str(path)!r} is corrupt or not a mara_mjx checkpoint: {e}"
        ) from e
    found = meta.get("format") if isinstance(meta, dict) else None
    if found != FORMAT:
        raise CheckpointError(f"checkpoint {str(path)!r} has format {found!r}, expected {FORMAT!r}")
    required = ("env_name", "env_config", "ppo", "run", "eval", "progress")
    for key in (*required, "observation_size", "action_size"):
        if key not in meta:
            raise CheckpointError(f"checkpoint {str(path)!r} metadata lacks {key!r}")
    from mara_mjx.ppo.config import upgrade_meta

    try:  # one written before the PPOConfig split: its flat "ppo" in three sections
        return arrays, upgrade_meta(meta)
    except ValueError as e:
        raise CheckpointError(f"checkpoint {str(path)!r}: {e}") from e


def list_checkpoints(run_dir: str | os.PathLike) -> list[Path]:
    """Checkpoints of a run folder, oldest first."""
    folder = Path(run_dir) / CHECKPOINT_DIR
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _NAME.match(p.name))]
    return [p for _, p in sorted(found)]


def find_checkpoint(path: str | os.PathLike, warn: Any = None) -> Path:
    """A checkpoint file as given, or the newest readable one of a run folder.

    A run folder's newest checkpoint that does not load (truncated by a crash or a full
    disk, say) is skipped for the next older one; `warn(message)` (default: print to
    stderr) names the skipped file and the one used. CheckpointError when none loads.
    """
    path = Path(path)
    if not path.is_dir():
        if not path.exists():
            raise CheckpointError(f"checkpoint or run folder {str(path)!r} does not exist")
        return path
    found = list_checkpoints(path)
    if not found:
        raise CheckpointError(
            f"run folder {str(path)!r} has no checkpoints (expected "
            f"{CHECKPOINT_DIR}/ckpt_<update>.npz inside it); if its run was stopped before "
            "the first checkpoint, start it again with the same --out"
        )
    skipped = []
    for candidate in reversed(found):
        try:
            load_checkpoint(candidate)
        except CheckpointError as e:
            skipped.append(f"{candidate.name} ({e})")
            continue
        if skipped:
            message = (
                f"warning: skipped unreadable checkpoint(s) {'; '.join(skipped)}; using {candidate}"
            )
            (warn or _stderr)(message)
        return candidate
    raise CheckpointError(
        f"no checkpoint of run folder {str(path)!r} is readable: {'; '.join(skipped)}"
    )


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)
