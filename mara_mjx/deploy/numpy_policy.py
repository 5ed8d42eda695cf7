"""The exported .npz policy in numpy: `NumpyPolicy` and its loader. numpy only (and its
sibling ik_numpy.py), so that the robot-side runner (runner.py) runs the same code
without JAX; `mara_mjx.cli.export` writes the file (its module docstring: the layout).

    from mara_mjx.deploy.numpy_policy import load_exported   # or mara_mjx.cli.export's
    policy = load_exported("policy.npz")
    action = policy(obs)          # (obs_size,) or (N, obs_size) -> (..., 6) rad, float32

What `policy(obs)` computes is what `mara_mjx.ppo.make_policy` computes (the
deterministic Gaussian mean), in float64: z = clip((obs - mean) / sqrt(var + 1e-8),
-obs_clip, obs_clip) when the run normalised observations (else z = obs), where obs first
has its quaternion block obs[quat_index:quat_index + 4] multiplied by the sign of its w
when the run used `canonical_quat` (quat_index >= 0 in the meta), z[..., hidden_obs] = 0,
then the actor's tanh MLP (linear output layer); with `relative_actions` its output d
becomes m tanh(d / m) when max_joint_step m > 0, then a policy with an IK finish
(PolicyConfig.ik_finish; format mara_mjx.export/2, meta "ik_finish") replaces that
displacement near the target by the IK step (ik_numpy.NumpyFinish, e = obs[6:9]), and
obs[..., :6] (the current joint positions) is added. The action is an absolute joint
target (rad) for motor1..motor6; the env clips it to the joint limits (`policy(obs,
clip=True)` does the same here) and the result is cast to float32. `policy.act(obs)` is
the float64 action before the clip and the cast (the runner's).
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

if __package__:  # imported as mara_mjx.deploy.numpy_policy
    from mara_mjx.deploy import ik_numpy
else:  # a copied file, loaded by path (runner.py's docstring): its sibling ik_numpy.py
    _sibling = Path(__file__).with_name("ik_numpy.py")
    if not _sibling.is_file():
        raise ImportError(
            f"{__file__} needs ik_numpy.py next to it (copy mara_mjx/deploy/ik_numpy.py "
            "into the same folder)"
        )
    _spec = importlib.util.spec_from_file_location("mara_runner_ik_numpy", _sibling)
    ik_numpy = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(ik_numpy)

FORMAT = "mara_mjx.export/1"
FORMAT_FINISH = "mara_mjx.export/2"
"""The format of a file that keeps an IK finish (meta "ik_finish"): a reader of /1 alone
would run the policy without it, so such files say /2 and older readers refuse them."""
FORMATS = (FORMAT, FORMAT_FINISH)
SUFFIXES = (".npz", ".onnx")
"""The exported files: numpy (this module) and ONNX (onnx_policy.py, onnx_graph.py)."""
OBS_VAR_EPS = 1e-8  # mara_mjx.ppo.networks.normalize
META_KEY = "__meta__"  # mara_mjx/runtime/npzmeta.py's (tests/test_runner.py holds them equal)
COMMIT_STALL_RAD = 0.002
"""rad: an arm none of whose joints moved more than this in a control period has stopped
(`committed`)."""
# What reading a damaged or foreign .npz can raise (npzmeta.NPZ_ERRORS)
_NPZ_ERRORS = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile)


def committed(
    q: Any, new: Any, held: Any, q_previous: Any, tol: float, lower: Any, upper: Any, xp: Any = np
) -> Any:
    """PolicyConfig.commit_rad's rule, in numpy or jax.numpy (`xp`), for arrays (..., 6):
    the joint targets to send at observed joints `q`, given the policy's `new` targets,
    the targets sent last (`held`) and the joints observed then (`q_previous`). `held` is
    sent again while the arm has not arrived (some joint farther than `tol` rad from it)
    and still moves (some joint moved more than COMMIT_STALL_RAD since `q_previous`);
    otherwise `new`, clipped to [lower, upper]. Start an episode with held = q_previous =
    q (arrived: the first targets are the policy's)."""
    choose = deciding(q, held, q_previous, tol, xp)[..., None]
    return xp.where(choose, xp.clip(new, lower, upper), held)


def deciding(q: Any, held: Any, q_previous: Any, tol: float, xp: Any = np) -> Any:
    """(..., 6) -> (...,) bool: where `committed` sends the policy's new targets (the arm
    arrived within `tol` of `held`, or stopped); elsewhere the new targets are not used, so
    a runner need not compute them there."""
    arrived = xp.max(xp.abs(q - held), axis=-1) <= tol
    stopped = xp.max(xp.abs(q - q_previous), axis=-1) <= COMMIT_STALL_RAD
    return arrived | stopped


class ExportError(ValueError):
    """A missing or corrupt checkpoint or exported file, or an output that cannot be
    written (mara_mjx.cli.export raises it too)."""


@dataclasses.dataclass(frozen=True)
class NumpyPolicy:
    """The exported deterministic policy, numpy only. `policy(obs)` -> action (rad)."""

    kernels: tuple[np.ndarray, ...]
    """(in, out) per layer; tanh after every layer but the last."""
    biases: tuple[np.ndarray, ...]
    obs_mean: np.ndarray | None
    """(obs_size,) or None when the run did not normalise observations."""
    obs_var: np.ndarray | None
    meta: dict[str, Any]
    """The file's metadata (mara_mjx/cli/export.py's module docstring)."""

    @property
    def observation_size(self) -> int:
        return int(self.meta["observation_size"])

    @property
    def action_size(self) -> int:
        return int(self.meta["action_size"])

    @property
    def env_name(self) -> str:
        return str(self.meta["env_name"])

    @property
    def joint_lower(self) -> np.ndarray:
        """(6,) rad."""
        return np.asarray(self.meta["action"]["lower"], np.float32)

    @property
    def joint_upper(self) -> np.ndarray:
        """(6,) rad."""
        return np.asarray(self.meta["action"]["upper"], np.float32)

    @property
    def observation_layout(self) -> dict[str, slice]:
        """Observation part name -> slice of the last axis."""
        return {p["name"]: slice(p["start"], p["stop"]) for p in self.meta["observation_layout"]}

    # constants of `act`, prepared once (float64 as every step computes them)
    @functools.cached_property
    def _kernels(self) -> tuple[np.ndarray, ...]:
        return tuple(k.astype(np.float64) for k in self.kernels)

    @functools.cached_property
    def _obs_std(self) -> np.ndarray | None:
        """sqrt(var + eps) of the normaliser (obs_var_eps of the meta), or None."""
        if self.obs_var is None:
            return None
        eps = float(self.meta.get("obs_var_eps", OBS_VAR_EPS))
        return np.sqrt(self.obs_var.astype(np.float64) + eps)

    @functools.cached_property
    def _finish(self) -> Any:
        """The meta's IK finish (ik_numpy.NumpyFinish), or None."""
        if not self.meta.get("ik_finish"):
            return None
        return ik_numpy.NumpyFinish(self.meta["ik_finish"])

    def __call__(self, obs: Any, clip: bool = False) -> np.ndarray:
        """obs (..., obs_size) raw observation -> action (..., action_size) float32 rad.
        `clip`: clip to the joint limits as the env does (make_policy does not)."""
        x = np.asarray(obs)
        if x.dtype.kind not in "biuf":
            raise ValueError(f"obs must be numeric, got dtype {x.dtype}")
        if x.ndim < 1 or x.shape[-1] != self.observation_size:
            raise ValueError(
                f"obs must have shape (..., {self.observation_size}) for {self.env_name}, "
                f"got {x.shape}"
            )
        x = self.act(x.astype(np.float64))
        if clip:
            x = np.clip(x, self.joint_lower, self.joint_upper)
        return x.astype(np.float32)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """obs (..., obs_size) float64, unchecked (`obs` is not modified) -> the action
        (..., action_size) float64 rad, unclipped (module docstring)."""
        x = raw = obs
        quat = int(self.meta.get("quat_index", -1))
        if quat >= 0:  # canonical sign, w >= 0 (PolicyConfig.canonical_quat)
            x = x.copy()
            sign = np.where(x[..., quat : quat + 1] < 0, -1.0, 1.0)
            x[..., quat : quat + 4] *= sign
        if self.obs_mean is not None:
            clip_obs = float(self.meta["obs_clip"])
            x = np.clip((x - self.obs_mean) / self._obs_std, -clip_obs, clip_obs)
        hidden = self.meta.get("hidden_obs", [])
        if hidden:
            x = x.copy() if x is raw else x
            x[..., hidden] = 0.0
        for i, (kernel, bias) in enumerate(zip(self._kernels, self.biases, strict=True)):
            x = x @ kernel + bias
            if i < len(self.kernels) - 1:
                x = np.tanh(x)
        if self.meta.get("relative_actions", False):
            step = float(self.meta.get("max_joint_step", 0.0))
            if step > 0.0:  # PolicyConfig.max_joint_step
                x = step * np.tanh(x / step)
            if self._finish is not None:  # PolicyConfig.ik_finish
                x = self._finish(raw[..., : self.action_size], raw[..., 6:9], x)
            x = x + raw[..., : self.action_size]
        return x


def _read_npz(path: Path) -> tuple[dict[str, np.ndarray], Any]:
    """The arrays of an .npz with a JSON `META_KEY` entry, and that entry decoded
    (npzmeta.read_npz_with_meta, numpy only); one of _NPZ_ERRORS on a damaged file."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return arrays, json.loads(str(arrays.pop(META_KEY)))


def load_exported(path: str | os.PathLike) -> NumpyPolicy:
    """The `NumpyPolicy` of an .npz written by `python -m mara_mjx.export`; ExportError
    if missing, corrupt or not such a file."""
    path = Path(path)
    if not path.is_file():
        raise ExportError(f"exported policy {str(path)!r} does not exist (or is not a file)")
    try:
        arrays, meta = _read_npz(path)
    except _NPZ_ERRORS as e:
        raise ExportError(
            f"{str(path)!r} is corrupt or not an exported mara_mjx policy: {e}"
        ) from e
    if not isinstance(meta, dict) or meta.get("format") not in FORMATS:
        found = meta.get("format") if isinstance(meta, dict) else None
        raise ExportError(f"{str(path)!r} has format {found!r}, expected one of {FORMATS}")
    return from_arrays(arrays, meta, str(path))


def from_arrays(arrays: Any, meta: dict[str, Any], where: str = "the export") -> NumpyPolicy:
    """The `NumpyPolicy` of an export's arrays (layer_<i>/kernel, ...) and meta;
    ExportError where they do not fit together."""
    if meta.get("activation", "tanh") != "tanh":
        raise ExportError(f"{where!r}: activation {meta['activation']!r}, expected 'tanh'")
    n_layers = len(meta["hidden_sizes"]) + 1
    try:
        kernels = tuple(arrays[f"layer_{i}/kernel"] for i in range(n_layers))
        biases = tuple(arrays[f"layer_{i}/bias"] for i in range(n_layers))
        stats = (arrays["obs_mean"], arrays["obs_var"]) if meta["normalize_obs"] else (None, None)
    except KeyError as e:
        raise ExportError(f"{where!r} lacks the array {e}") from e
    if (
        kernels[0].shape[0] != meta["observation_size"]
        or kernels[-1].shape[1] != (meta["action_size"])
    ):
        raise ExportError(f"{where!r}: layer shapes do not match the observation/action sizes")
    return NumpyPolicy(kernels, biases, stats[0], stats[1], meta)
