"""An exported policy file (.onnx or .npz) in the simulator's closed loop, for
`python -m mara_mjx.evaluate policy.onnx`.

    from mara_mjx.deploy import in_the_loop
    export = in_the_loop.load("policy.onnx")        # or an exported .npz
    env = in_the_loop.make_env(export, driver="real")   # the export's env (+ overrides)
    result = evaluation.evaluate(env, export.policy, config)   # the checkpoint's code path

The file runs where the robot runs it: `PolicyRunner.load` (onnxruntime on one CPU thread
for .onnx, the runner's float64 numpy for .npz), given the env's observation as it is
(the runner's own observation builder is held equal to the env's in tests/test_runner.py).
`export.policy` is a pytree callable like `Policy`, so the jitted evaluation
(`ppo.evaluation.make_evaluate`, `ppo.target_eval.evaluate_targets`) runs it unchanged:
each env step calls the file once through `jax.pure_callback`, batched over the episodes
(float32 in and out, as the env's own policy; leading axes are flattened into the file's
one batch axis, so a vmap over the evaluation works too). The env clips the targets to the
joint limits as it clips the JAX policy's. Every metric, reset key, episode and the report
are the checkpoint's; only the policy differs.

The env: the export's `env_name` and `env_config` (or another registered env), with
EnvConfig overrides on top; refused (InTheLoopError) when its observation layout (names
and slices) is not the one the file was exported for.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.deploy.runner import SUFFIXES, PolicyRunner, RunnerError


class InTheLoopError(ValueError):
    """An export that cannot run in this env (or is not an export at all)."""


@dataclasses.dataclass(frozen=True)
class Export:
    """A loaded export: its path, sha256, metadata and the jittable policy."""

    path: Path
    sha256: str
    meta: dict[str, Any]
    policy: Any  # jax.tree_util.Partial: obs (..., obs_size) -> (..., action_size) float32

    def describe(self) -> dict[str, Any]:
        """What a report says about the file it evaluated."""
        keys = ("format", "source", "recipe", "rules_in_graph", "ik_finish_dropped")
        return {
            "path": str(self.path),
            "sha256": self.sha256,
            **{k: self.meta[k] for k in keys if k in self.meta},
        }


def is_export_path(path: str | Path) -> bool:
    """Whether evaluate's positional argument names an exported file rather than a
    checkpoint: any .onnx, or a .npz holding an export's metadata."""
    path = Path(path)
    if path.suffix == ".onnx":
        return True
    if path.suffix != ".npz" or not path.is_file():
        return False
    from mara_mjx.cli.export import is_exported

    return is_exported(path)


def load(path: str | Path) -> Export:
    """The export at `path` (.onnx or .npz), ready for the jitted evaluation."""
    path = Path(path)
    if path.suffix not in SUFFIXES:
        raise InTheLoopError(f"{str(path)!r} is not an exported policy (.onnx or .npz)")
    try:
        runner = PolicyRunner.load(path)
    except RunnerError as e:
        raise InTheLoopError(str(e)) from e
    meta = runner.meta
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return Export(path, digest, meta, host_policy(runner.act, int(meta["action_size"])))


def commit_rad(meta: dict[str, Any]) -> float:
    """The export's PolicyConfig.commit_rad (0 for files written before it): the evaluation
    loop applies it around the file's policy, as the runner does (EvalConfig.commit_rad)."""
    return float(meta.get("commit_rad", 0.0))


def host_policy(fn: Any, action_size: int) -> Any:
    """A jittable pytree callable obs (..., obs_size) -> (..., action_size) float32 that
    runs the host function `fn` ((N, obs_size) float64 -> (N, action_size)) through
    `jax.pure_callback`."""
    # Partial keeps its function in the treedef (static): no leaves, one compile per file
    return jax.tree_util.Partial(functools.partial(_call, _Host(fn, action_size)))


class _Host:
    """`fn` on numpy, leading axes flattened; hashable by identity (jit's cache key)."""

    def __init__(self, fn: Any, action_size: int):
        self.fn, self.action_size = fn, action_size

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        flat = obs.reshape(-1, obs.shape[-1]).astype(np.float64)
        out = np.asarray(self.fn(flat), np.float32)
        return out.reshape(obs.shape[:-1] + (self.action_size,))


def _call(host: _Host, obs: jax.Array) -> jax.Array:
    shape = jax.ShapeDtypeStruct(obs.shape[:-1] + (host.action_size,), jnp.float32)
    return jax.pure_callback(host, shape, obs, vmap_method="broadcast_all")


def make_env(export: Export, env_name: str | None = None, **overrides: Any):
    """The env to evaluate `export` in: `env_name` (default the export's) built from the
    export's env_config with `overrides` (EnvConfig fields) on top; InTheLoopError if it
    cannot be built or observes another layout than the file's."""
    from mara_mjx.ppo.checkpoint import CheckpointError
    from mara_mjx.runtime import runs

    meta = export.meta
    name = env_name or meta["env_name"]
    try:
        env = runs.make_env({**meta, "env_name": name}, **overrides)
    except CheckpointError as e:
        raise InTheLoopError(f"{export.path}: {e}") from e
    check_layout(meta, env, str(export.path))
    return env


def check_layout(meta: dict[str, Any], env: Any, where: str) -> None:
    """InTheLoopError unless `env` observes the parts (names and slices) the export
    was made for."""
    parts = lambda layout: [(p["name"], p["start"], p["stop"]) for p in layout]  # noqa: E731
    ours, theirs = parts(meta["observation_layout"]), parts(env.observation_layout)
    if ours != theirs:
        raise InTheLoopError(
            f"{where} was exported for the observation {ours} ({meta['env_name']}), but "
            f"the env observes {theirs}; evaluate it in an env of its layout"
        )
