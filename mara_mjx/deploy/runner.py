"""The robot-side runner: an exported policy, its observation built from the arm's joints
and a target pose, the next joint targets every control period. numpy (+ onnxruntime for
.onnx); no JAX, no ROS.

    from mara_mjx.deploy.runner import PolicyRunner
    runner = PolicyRunner.load("policy.npz")         # or "policy.onnx"
    runner.reset()                                   # a new episode (the arm at rest)
    every runner.control_dt seconds (0.05 s):
        targets = runner.step(q, target_pos, target_quat)   # q (6,) rad -> (6,) rad

On a robot without JAX, copy this file and its siblings `numpy_policy.py` (the .npz
policy) and `ik_numpy.py` (the arm's forward kinematics and the IK finish) into one
folder, next to the exported policy, and load it by path; importing
`mara_mjx.deploy.runner` imports the `mara_mjx` package, which imports JAX:

    import importlib.util
    spec = importlib.util.spec_from_file_location("mara_runner", "/opt/mara/runner.py")
    mara_runner = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mara_runner)             # imports numpy only
    runner = mara_runner.PolicyRunner.load("/opt/mara/policy.npz")

`step(joint_positions, target_pos, target_quat=None)`: joint_positions (6,) or (N, 6) rad,
motor1..motor6 as the encoders read them; target_pos (3,) or (N, 3) m and target_quat
(4,) or (N, 4) (w, x, y, z), the target TCP pose in the world frame (the env's: the robot
base at (0, 0, 0.645) on the table). target_quat None: the export's env target (the
task's). Returns the joint targets (6,) or (N, 6) float64 rad, clipped to the joint
limits, for the arm to reach by the next call. The runner keeps each arm's previous joint
positions and targets (the batch size is fixed from the first step after `reset()`).
An export with commit_rad > 0 (PolicyConfig.commit_rad) sends the previous targets again
until the arm is within commit_rad of them on every joint or has stopped, and only then
the policy's new ones (numpy_policy.committed, the evaluation loop's rule); the policy is
not run for an arm while its command is held, so only the steps that choose pay for it.

The observation is built exactly as the env builds it (mara_mjx/envs/mara.py), from the
export's `observation_layout`:
    q         the joint positions given
    e         p_tcp(q) - target_pos (m)
    quat_err  quat_tcp(q) (x) conj(unit target_quat), quat_tcp with w >= 0 (Orient tasks)
    v         J_pos(q) qvel (m/s), qvel = (q - q_previous) / control_dt, 0 on the first
              step after reset: the train driver's qvel (its joints reach each command
              within one control period); on a real arm, a finite-difference estimate
A layout with any other part, or parts of other sizes, is refused at load.

Forward kinematics: ik_numpy.NumpyFinish.frames over the chain the export carries (an
export with an IK finish has it in meta["ik_finish"]["chain"]); an export without one
gets NOMINAL_CHAIN, the MARA chain of the spec's joint table (the same as the package's
model: tests/test_runner.py). quat_tcp composes the same chain's rotations as
quaternions (ik_numpy's frames return positions and axes only).

The policy: .onnx runs in an onnxruntime session (its "action" output; the file keeps its
metadata in metadata_props["mara_mjx"]); .npz runs `numpy_policy.NumpyPolicy.act`, the
code of `mara_mjx.cli.export.load_exported` (numpy_policy.py's module docstring:
quaternion sign, normaliser, hidden observations, the tanh MLP, max_joint_step, the IK
finish, relative actions) in float64; tests/test_runner.py holds both equal to the JAX
policy. Formats other than mara_mjx.export/1 and /2 are refused.
"""

from __future__ import annotations

import importlib.util
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

if __package__:  # imported as mara_mjx.deploy.runner
    from mara_mjx.deploy import ik_numpy, numpy_policy
else:  # a copied file, loaded by path: its siblings (numpy_policy.py loads ik_numpy.py)
    _sibling = Path(__file__).with_name("numpy_policy.py")
    if not _sibling.is_file():
        raise ImportError(
            f"{__file__} needs numpy_policy.py and ik_numpy.py next to it (copy them from "
            "mara_mjx/deploy/ into the same folder)"
        )
    _spec = importlib.util.spec_from_file_location("mara_runner_numpy_policy", _sibling)
    numpy_policy = importlib.util.module_from_spec(_spec)
    sys.modules[_spec.name] = numpy_policy  # where its dataclass looks its module up
    _spec.loader.exec_module(numpy_policy)
    ik_numpy = numpy_policy.ik_numpy

FORMATS = numpy_policy.FORMATS
SUFFIXES = numpy_policy.SUFFIXES
PART_SIZES = {"q": 6, "e": 3, "quat_err": 4, "v": 3}
"""The observation parts the runner builds, and their sizes."""

# The MARA chain of the spec's joint table (mara_mjx/envs/chain.py's fields): the base on
# the table top, unrotated; every joint origin unrotated; hinge axes +-x, +z; anchors at
# the body origins; the TCP 0.24 m along the flange's z.
_EYE = np.eye(3).tolist()
NOMINAL_CHAIN = {
    "base_pos": [0.0, 0.0, 0.645],
    "base_rot": _EYE,
    "body_pos": [
        [0.0, 0.0, 0.06874],
        [0.118, 0.0, 0.1637],
        [-0.009, 0.0, 0.2],
        [-0.109255, 0.0, 0.149255],
        [0.105457, 0.0, 0.16074],
        [-0.10625569, 0.0, 0.14675569],
    ],
    "body_rot": [_EYE] * 6,
    "axis": [[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 0, 1], [-1, 0, 0], [0, 0, 1]],
    "anchor": [[0.0, 0.0, 0.0]] * 6,
    "site": [0.0, 0.0, 0.24],
}


class RunnerError(ValueError):
    """An export the runner cannot run, or inputs it cannot use."""


class PolicyRunner:
    """An exported policy with the state of its arms; see the module docstring."""

    def __init__(self, policy: Any, meta: dict[str, Any], where: str = "the export"):
        """`policy`: fn(obs (N, obs_size) float64) -> actions (N, 6) rad, unclipped;
        `meta`: the export's metadata. Use `PolicyRunner.load(path)`."""
        self.meta = meta
        self._policy = policy
        self.layout = _check_layout(meta, where)
        action = meta["action"]
        self.joint_names: tuple[str, ...] = tuple(action["joint_names"])
        self.joint_lower = np.asarray(action["lower"], np.float64)
        self.joint_upper = np.asarray(action["upper"], np.float64)
        env = meta.get("env_config", {})
        self.control_dt = float(env.get("control_dt", 0.05))
        """Seconds between steps: the env's control period, which qvel divides by."""
        self.default_target_quat = _unit(np.asarray(env.get("target_quat", (1, 0, 0, 0)), float))
        chain = (meta.get("ik_finish") or {}).get("chain") or meta.get("chain") or NOMINAL_CHAIN
        self._fk = ik_numpy.NumpyFinish(
            {"chain": chain, "joint_lower": action["lower"], "joint_upper": action["upper"]}
        )
        c = self._fk.chain
        # quat (x) body_i (x) (cos(q_i / 2), sin(q_i / 2) axis_i), for row quaternions:
        # cos(q_i / 2) quat @ B_i + sin(q_i / 2) quat @ B_i A_i, with constant 4 x 4
        # right-multiplication matrices (B_i of the body's rotation, A_i of (0, axis_i))
        self._base_quat = _mat_to_quat(c["base_rot"])[None]
        self._body = [_right(_mat_to_quat(rot)) for rot in c["body_rot"]]
        self._body_axis = [
            b @ _right([0.0, *a]) for b, a in zip(self._body, c["axis"], strict=True)
        ]
        self._quat_err = "quat_err" in self.layout
        self._v = "v" in self.layout
        self.commit_rad = float(meta.get("commit_rad", 0.0))
        """rad, > 0: each command is held until the arm arrives or stops (the export's
        PolicyConfig.commit_rad; numpy_policy.committed)."""
        self.reset()

    @classmethod
    def load(cls, path: str | os.PathLike, threads: int = 1) -> PolicyRunner:
        """The runner of an exported policy: `.npz` (numpy) or `.onnx` (onnxruntime, run
        on `threads` CPU threads). RunnerError for any other file."""
        path = Path(path)
        if path.suffix not in SUFFIXES:
            raise RunnerError(
                f"{str(path)!r}: the runner loads an exported policy ending in .npz "
                "(numpy) or .onnx (onnxruntime), written by python -m mara_mjx.export"
            )
        if not path.is_file():
            raise RunnerError(f"exported policy {str(path)!r} does not exist (or is not a file)")
        if path.suffix == ".onnx":
            policy, meta = _load_onnx(path, threads)
        else:
            policy, meta = _load_npz(path)
        return cls(policy, meta, str(path))

    @property
    def act(self) -> Any:
        """The file's policy alone: obs (N, obs_size) float64 -> (N, 6) rad, unclipped."""
        return self._policy

    @property
    def observation_size(self) -> int:
        return int(self.meta["observation_size"])

    def reset(self) -> None:
        """A new episode: the arms are at rest (qvel 0 at the next step); the batch size
        is set again by the next step."""
        self._previous: np.ndarray | None = None
        self._held: np.ndarray | None = None

    def observe(self, joint_positions: Any, target_pos: Any, target_quat: Any = None) -> np.ndarray:
        """The observation (obs_size,) or (N, obs_size) float64 the next `step` gives the
        policy for these inputs; the runner's state is left as it is."""
        q, target_pos, target_quat, single = self._inputs(joint_positions, target_pos, target_quat)
        obs = self._observe(q, target_pos, target_quat)
        return obs[0] if single else obs

    def step(self, joint_positions: Any, target_pos: Any, target_quat: Any = None) -> np.ndarray:
        """Joint positions (6,) or (N, 6) rad and the target pose -> the joint targets (6,)
        or (N, 6) float64 rad, clipped to the joint limits (module docstring); with the
        export's commit_rad, the targets of the last step again while the arm carries them
        out."""
        q, target_pos, target_quat, single = self._inputs(joint_positions, target_pos, target_quat)
        obs = self._observe(q, target_pos, target_quat)
        if self.commit_rad > 0.0:
            held = q if self._held is None else self._held
            previous = q if self._previous is None else self._previous
            # the policy runs only for the arms whose new targets are sent: while an arm
            # carries out a held command it costs nothing (numpy_policy.committed's rule;
            # a plan's restarts can take longer than the control period)
            decide = numpy_policy.deciding(q, held, previous, self.commit_rad)
            action = held.copy()
            if decide.any():
                action[decide] = self._act(obs[decide])
        else:
            action = self._act(obs)
        self._previous, self._held = q, action
        return action[0] if single else action

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """The policy's joint targets for observations (n, obs_size), clipped to the joint
        limits; RunnerError where any is not finite."""
        action = self._policy(obs)
        if not np.all(np.isfinite(action)):
            raise RunnerError("the policy returned non-finite joint targets; not sent")
        return np.clip(action, self.joint_lower, self.joint_upper)

    # -------------------------------------------------------------- internals
    def _inputs(
        self, joint_positions: Any, target_pos: Any, target_quat: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """Checked (N, 6), (N, 3), (N, 4) float64 arrays and whether the call was unbatched."""
        q = _array("joint_positions", joint_positions, 6)
        single = q.ndim == 1
        q = q.reshape(-1, 6)
        n = q.shape[0]
        if self._previous is not None and self._previous.shape[0] != n:
            raise RunnerError(
                f"joint_positions has {n} arm(s), the episode started with "
                f"{self._previous.shape[0]}; call reset() to change the batch size"
            )
        pos = _array("target_pos", target_pos, 3, n)
        if target_quat is None:
            quat = self.default_target_quat[None]
        else:
            quat = _array("target_quat", target_quat, 4, n).reshape(-1, 4)
            norm = np.linalg.norm(quat, axis=-1, keepdims=True)
            if np.any(norm < 1e-6):
                raise RunnerError("target_quat must be a non-zero quaternion (w, x, y, z)")
            quat = quat / norm
        return q, pos.reshape(-1, 3), quat, single

    def _observe(self, q: np.ndarray, target_pos: np.ndarray, target_quat: np.ndarray):
        tcp, axes, anchors = self._fk.frames(q)
        parts = {"q": q, "e": tcp - target_pos}
        if self._quat_err:
            conj = target_quat * np.array([1.0, -1.0, -1.0, -1.0])
            parts["quat_err"] = ik_numpy.quat_mul(self._tcp_quat(q), conj)
        if self._v:
            if self._previous is None:
                parts["v"] = np.zeros_like(tcp)
            else:
                qvel = (q - self._previous) / self.control_dt
                jac = np.cross(axes, tcp[:, None, :] - anchors)  # (N, 6, 3): J_pos's columns
                parts["v"] = np.einsum("nij,ni->nj", jac, qvel)
        obs = np.empty((q.shape[0], self.observation_size))
        for name, part in self.layout.items():
            obs[:, part] = parts[name]
        return obs

    def _tcp_quat(self, q: np.ndarray) -> np.ndarray:
        """(N, 4) (w, x, y, z), w >= 0: the flange's (and TCP's) orientation, world frame."""
        half = 0.5 * q
        cos, sin = np.cos(half), np.sin(half)
        quat = self._base_quat
        for i in range(6):
            quat = cos[:, i : i + 1] * (quat @ self._body[i]) + sin[:, i : i + 1] * (
                quat @ self._body_axis[i]
            )
        return np.where(quat[:, :1] < 0, -quat, quat)


def _array(name: str, value: Any, size: int, n: int | None = None) -> np.ndarray:
    """`value` as float64 of shape (size,) or (n, size) (any n > 0 when n is None);
    RunnerError otherwise, or where a value is not finite."""
    x = np.asarray(value)
    if x.dtype.kind not in "biuf":
        raise RunnerError(f"{name} must be numeric, got dtype {x.dtype}")
    batched = x.ndim == 2 and x.shape[1] == size and x.shape[0] == (n or x.shape[0]) > 0
    if x.shape != (size,) and not batched:
        want = f"({size},) or ({n or 'N'}, {size})"
        raise RunnerError(f"{name} must have shape {want}, got {x.shape}")
    x = x.astype(np.float64)
    if not np.all(np.isfinite(x)):
        raise RunnerError(f"{name} has non-finite values: {x.tolist()}")
    return x


def _check_layout(meta: dict[str, Any], where: str) -> dict[str, slice]:
    """The export's observation layout as name -> slice; RunnerError unless the runner
    builds every part and the parts tile the observation."""
    if meta.get("format") not in FORMATS:
        raise RunnerError(
            f"{where!r} has format {meta.get('format')!r}; this runner runs {FORMATS}"
        )
    layout, start = {}, 0
    for part in meta.get("observation_layout", []):
        name, lo, hi = part["name"], int(part["start"]), int(part["stop"])
        if name not in PART_SIZES or hi - lo != PART_SIZES[name] or lo != start:
            raise RunnerError(
                f"{where!r}: observation part {name!r} [{lo}, {hi}) is not one the runner "
                f"builds; it builds {PART_SIZES} (name: size), in consecutive slices from 0"
            )
        layout[name] = slice(lo, hi)
        start = hi
    if "q" not in layout or start != int(meta["observation_size"]):
        raise RunnerError(
            f"{where!r}: the observation layout {list(layout)} does not cover the "
            f"observation of size {meta['observation_size']} from q on"
        )
    return layout


def _unit(quat: np.ndarray) -> np.ndarray:
    return quat / np.linalg.norm(quat)


def _right(b: Any) -> np.ndarray:
    """The (4, 4) matrix R with a @ R = a (x) b for row quaternions a (..., 4)."""
    return ik_numpy.quat_mul(np.eye(4), np.asarray(b, np.float64)[None])


def _mat_to_quat(m: Any) -> np.ndarray:
    """A (3, 3) rotation -> (w, x, y, z), w >= 0 (Shepperd's method, as envs/chain.py;
    once per chain, at load)."""
    m = np.asarray(m, np.float64)
    tr = np.trace(m)
    candidates = [
        [1.0 + tr, m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]],
        [
            m[2, 1] - m[1, 2],
            1.0 + m[0, 0] - m[1, 1] - m[2, 2],
            m[0, 1] + m[1, 0],
            m[0, 2] + m[2, 0],
        ],
        [
            m[0, 2] - m[2, 0],
            m[0, 1] + m[1, 0],
            1.0 - m[0, 0] + m[1, 1] - m[2, 2],
            m[1, 2] + m[2, 1],
        ],
        [
            m[1, 0] - m[0, 1],
            m[0, 2] + m[2, 0],
            m[1, 2] + m[2, 1],
            1.0 - m[0, 0] - m[1, 1] + m[2, 2],
        ],
    ]
    quat = _unit(np.array(candidates[int(np.argmax([tr, m[0, 0], m[1, 1], m[2, 2]]))]))
    return -quat if quat[0] < 0 else quat


# ------------------------------------------------------------------ the policies
def _load_npz(path: Path) -> tuple[Any, dict[str, Any]]:
    try:
        policy = numpy_policy.load_exported(path)
    except numpy_policy.ExportError as e:
        raise RunnerError(str(e)) from e
    _check_layout(policy.meta, str(path))
    return policy.act, policy.meta


def _load_onnx(path: Path, threads: int) -> tuple[Any, dict[str, Any]]:
    try:
        import onnxruntime as ort
    except ImportError as e:
        raise RunnerError(
            "running .onnx needs onnxruntime: pip install onnxruntime (or run the .npz "
            "export, numpy only)"
        ) from e
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = threads
    options.log_severity_level = 3  # errors only: a traced graph's load lists pruned constants
    try:
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        meta = json.loads(session.get_modelmeta().custom_metadata_map["mara_mjx"])
    except Exception as e:  # onnxruntime raises its own types for a foreign file
        raise RunnerError(f"{str(path)!r} is not an exported mara_mjx ONNX policy: {e}") from e
    _check_layout(meta, str(path))
    if meta.get("ik_finish"):
        raise RunnerError(f"{str(path)!r} claims an IK finish, which .onnx cannot run")

    fixed = session.get_inputs()[0].shape[0]  # `export --batch B`: B; any batch: a name
    fixed = fixed if isinstance(fixed, int) else None
    actions = int(meta["action_size"])

    def run(x: np.ndarray) -> np.ndarray:
        return session.run(["action"], {"obs": x})[0].astype(np.float64)

    def policy(obs: np.ndarray) -> np.ndarray:
        return in_batches(run, obs.astype(np.float32), fixed, actions)

    return policy, meta


def in_batches(run: Any, x: np.ndarray, fixed: int | None, actions: int) -> np.ndarray:
    """`run` (a file's call) on the rows of `x` (N, obs): at once where the file takes any
    batch (`fixed` None) or N; else `fixed` rows per call (`export --batch B`, 1 for a
    robot; evaluate's loop runs its episodes at once), the last call padded with copies of
    the last row, whose actions are dropped -> (N, actions)."""
    if fixed is None or len(x) == fixed:
        return run(x)
    n = len(x)
    padded = np.concatenate([x, np.repeat(x[-1:], -n % fixed, axis=0)]) if n else x
    out = [run(padded[i : i + fixed]) for i in range(0, len(padded), fixed)]
    return np.concatenate(out)[:n] if out else np.zeros((0, actions))
