"""Checkpoints: one .npz file per checkpoint, written atomically.

A checkpoint holds every leaf of the `RunnerState` (params, optimiser state, observation
statistics, the state of every env, the PRNG key, the update count) under a readable
name such as `params/params/actor/Dense_0/kernel`, plus a JSON `__meta__` entry with the
resolved config (env name and env config, ppo, run, eval), the host progress (update,
env steps as Python ints, wall-clock time, time-to-accuracy records), the versions of
python/jax/mujoco/flax/optax/numpy and the git commit when available. PRNG keys are
stored as their raw uint32 key data.

Writes go to a temporary file in the same folder, then `os.replace`, so a crash never
leaves a half-written checkpoint under the final name.
"""

from __future__ import annotations

import json
import os
import platform
import re
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.npzmeta import META_KEY, NPZ_ERRORS, read_npz_with_meta

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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = state_to_arrays(state)
    meta = {"format": FORMAT, **meta}
    arrays[META_KEY] = np.array(json.dumps(meta))
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


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
    return arrays, meta


def list_checkpoints(run_dir: str | os.PathLike) -> list[Path]:
    """Checkpoints of a run folder, oldest first."""
    folder = Path(run_dir) / CHECKPOINT_DIR
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _NAME.match(p.name))]
    return [p for _, p in sorted(found)]


def find_checkpoint(path: str | os.PathLike) -> Path:
    """A checkpoint file as given, or the newest one of a run folder."""
    path = Path(path)
    if path.is_dir():
        found = list_checkpoints(path)
        if not found:
            raise CheckpointError(
                f"run folder {str(path)!r} has no checkpoints (expected "
                f"{CHECKPOINT_DIR}/ckpt_<update>.npz inside it)"
            )
        return found[-1]
    if not path.exists():
        raise CheckpointError(f"checkpoint or run folder {str(path)!r} does not exist")
    return path


def run_dir_of(checkpoint: Path) -> Path:
    """The run folder a checkpoint belongs to."""
    parent = checkpoint.resolve().parent
    return parent.parent if parent.name == CHECKPOINT_DIR else parent


def prune_checkpoints(run_dir: str | os.PathLike, keep: int) -> None:
    """Delete all but the newest `keep` checkpoints of a run folder."""
    for old in list_checkpoints(run_dir)[:-keep]:
        old.unlink(missing_ok=True)


def env_overrides(env_config: dict[str, Any]) -> dict[str, Any]:
    """`make(name, **env_overrides(cfg))` rebuilds an env from `EnvConfig.to_dict()`."""
    flat = {k: v for k, v in env_config.items() if k != "reward"}
    flat.update(env_config.get("reward", {}))
    return flat


def make_env(meta: dict[str, Any], **overrides: Any):
    """The env a checkpoint was trained on (its saved name and config), with `overrides`
    (EnvConfig fields) on top; CheckpointError if the env is not registered, the options
    are invalid, or its observation size is not the policy's."""
    import mara_mjx

    name = meta["env_name"]
    if name not in mara_mjx.registered():
        raise CheckpointError(
            f"checkpoint env {name!r} is not registered; registered: {mara_mjx.registered()}"
        )
    try:
        env = mara_mjx.make(name, **{**env_overrides(meta["env_config"]), **overrides})
    except ValueError as e:
        raise CheckpointError(f"cannot build env {name}: {e}") from e
    if env.observation_size != meta["observation_size"]:
        raise CheckpointError(
            f"env {name} observes {env.observation_size} values, the policy expects "
            f"{meta['observation_size']}"
        )
    return env


def load_policy(path: str | os.PathLike):
    """The deterministic `Policy` of a checkpoint file or run folder."""
    return policy_from_checkpoint(*load_checkpoint(find_checkpoint(path)))


def policy_from_checkpoint(arrays: dict[str, np.ndarray], meta: dict[str, Any]):
    """The deterministic `Policy` from `load_checkpoint` output."""
    from mara_mjx.ppo.config import PPOConfig
    from mara_mjx.ppo.networks import RunningStats, make_network
    from mara_mjx.ppo.policy import Policy

    try:
        config = PPOConfig.from_dict(meta["ppo"])
    except (TypeError, ValueError) as e:
        raise CheckpointError(f"checkpoint holds an invalid PPO config: {e}") from e
    network = make_network(config, meta["action_size"])
    obs = jax.ShapeDtypeStruct((meta["observation_size"],), jnp.float32)
    template = jax.eval_shape(network.init, jax.random.key(0), obs, obs)
    params = arrays_to_state(arrays, template, prefix="params/")
    stats = None
    if config.normalize_obs:
        stats = arrays_to_state(arrays, RunningStats.create(meta["observation_size"]), "obs_stats/")
    return Policy(params=params, obs_stats=stats, config=config, action_size=meta["action_size"])


def write_json(path: str | os.PathLike, data: Any) -> Path:
    """Write `data` as indented JSON, atomically (temporary file + os.replace)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)
    return path


def check_writable(folder: str | os.PathLike) -> Path:
    """Create `folder` if needed and check a file can be written there; OSError if not."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    probe = folder / f".write-test-{os.getpid()}"
    probe.write_bytes(b"")
    probe.unlink()
    return folder


def provenance() -> dict[str, Any]:
    """Versions of the software that matters for reproducing a run, and the git commit."""
    versions = {"python": platform.python_version()}
    for package in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax", "numpy", "mara_mjx"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    versions["jax_backend"] = jax.default_backend()
    versions["devices"] = [str(d.device_kind) for d in jax.devices()]
    return {"versions": versions, "git_commit": git_commit()}


def git_commit() -> str | None:
    """HEAD of the repository this package lives in ('+dirty' if modified), or None."""
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5
        )
        if commit.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=5,
        )
        return commit.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None
