"""The MARA arm: model loading, the TCP pose, collision, and the two drivers.

Everything task-independent lives here; `mara.py` builds the tasks on top.

Physics state is three (6,) arrays, not a whole `mjx.Data`: joint positions `q`
(rad), velocities `qvel` (rad/s) and the servo references `ref` (rad, `real`
driver only). A step through MJX fills a constant `mjx.Data` template with them
and runs only the stages the driver needs, so the batched state that XLA carries
from step to step is 18 floats per arm instead of every field of `mjx.Data`.

Drivers (spec section 5):
  * `train`: the commanded joint positions are reached at once. q' = clip(a),
    qvel' = (q' - q) / control_dt, then the pose pass (`kinematics`: the lean
    pass of lean.py, or `mjx.kinematics` and `mjx.collision`). No dynamics.
  * `real`: each joint's servo reference moves toward the command at
    `velocity` rad/s; the arm's dynamics under servos kp (ref - q) + kv (ref_vel
    - qdot) (torque-limited to the effort limits, gravity fed forward) are
    integrated for control_dt / timestep substeps. The step has collided if any
    substep starts in penetration or the final pose penetrates. How contacts
    enter (`contacts`, EnvConfig.real_contacts):
      - 'detect' (the default): detected, not solved. The dynamics leave contacts
        out (joint limits, and the randomised friction loss, still act): with
        `kinematics` 'lean' the plain-jnp step of dynamics.py, with 'mjx'
        `mjx.step` of a copy of the model with MuJoCo's contact flag off
        (mjDSBL_CONTACT: MJX then has no contacts and no contact rows). Every
        substep's start pose and the final pose go through the pose pass in one
        vectorised call after the substeps.
      - 'physical': `mjx.step` solves the contact forces at every substep (the
        spec's wording, "contacts act physically"); the penetration is read from
        its own contacts.
    Why 'detect' is the default: every task puts the arm back at the reset pose
    at the end of a step that collided, and a contact row acts only once a pair
    penetrates, so up to a step's first penetrating substep the dynamics are the
    same (the lean step: to float rounding wherever MJX's 4-iteration constraint
    solve has converged, dynamics.py) and so are the trajectories, the collided
    flags and the resets (tests/test_real_fast.py). Only a colliding step's own
    observation and reward differ: they are those of its final pose, which under
    'detect' the arm reaches without being pushed back. And solving the contacts
    is most of the cost (benchmarks/real_driver_speed.py).
"""

from __future__ import annotations

import contextlib
import copy
import functools
import importlib.resources
import io
import itertools
from pathlib import Path
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mara_mjx.envs.dynamics import Dynamics
from mara_mjx.envs.fused_pose import arm_pose
from mara_mjx.envs.geometry import quat_canonical
from mara_mjx.envs.lean import LeanArm
from mara_mjx.envs.pose import ArmPose

if TYPE_CHECKING:
    from mujoco import mjx


def asset_path(name: str) -> Path:
    """A file of the MJCF assets: the installed package's `mara_mjx/assets/` (package data,
    see pyproject.toml), else a source checkout's top-level `assets/`."""
    try:
        installed = Path(str(importlib.resources.files("mara_mjx.assets") / name))
        if installed.is_file():
            return installed
    except ModuleNotFoundError:  # a source checkout (or an editable install): no such package
        pass
    return Path(__file__).resolve().parents[2] / "assets" / name


XML_PATH = asset_path("mara.xml")
JOINTS = ("motor1", "motor2", "motor3", "motor4", "motor5", "motor6")
# Joint velocity limit of the MARA servos (spec section 1): 1.57 rad/s = 90 deg/s.
MAX_JOINT_SPEED = 1.57
TABLE_TOP_Z = 0.645


def load_model(xml_path: str | Path = XML_PATH) -> mujoco.MjModel:
    """The C MuJoCo model of the arm, table, gripper and target marker."""
    path = Path(xml_path)
    if not path.is_file():
        raise FileNotFoundError(f"MJCF model not found: {path}")
    return mujoco.MjModel.from_xml_path(str(path))


def candidate_pairs(model: mujoco.MjModel) -> list[tuple[str, str]]:
    """Every pair of collision geoms (group 0, plus the table) that the spec counts as a
    collision: robot vs table, and robot bodies not joined by a joint; not the base
    resting on the table. assets/mara.xml lists a minimal covering subset of these
    (benchmarks/contact_pairs.py)."""
    names = [model.geom(i).name for i in range(model.ngeom) if model.geom_group[i] == 0]
    names = ["table", *[n for n in names if n and n != "table"]]
    body = {n: model.geom_bodyid[model.geom(n).id] for n in names}

    def joined(a: int, b: int) -> bool:
        return a == b or model.body_parentid[a] == b or model.body_parentid[b] == a

    return [
        (a, b)
        for a, b in itertools.combinations(names, 2)
        if not joined(body[a], body[b]) and {a, b} != {"table", "base"}
    ]


def with_pairs(xml_text: str, pairs: list[tuple[str, str]]) -> str:
    """The MJCF text with its <contact> block replaced by `pairs`."""
    start, end = xml_text.index("<contact>") + len("<contact>"), xml_text.index("</contact>")
    body = "\n".join(f'    <pair geom1="{a}" geom2="{b}"/>' for a, b in pairs)
    return xml_text[:start] + "\n" + body + "\n  " + xml_text[end:]


def _mjx():
    """mujoco.mjx, imported on first use. It prints "Failed to import warp" on import when
    the optional Warp backend is not installed; mara_mjx uses the JAX backend only, so the
    message is only noise here."""
    with contextlib.redirect_stdout(io.StringIO()):
        from mujoco import mjx
    return mjx


def _device() -> jax.Device:
    """This process's first device: MJX's default, jax.devices()[0], belongs to process 0
    when several processes share a run (mara_mjx.runtime.distributed), and a jitted function
    cannot close over another process's arrays."""
    return jax.local_devices()[0]


class Arm:
    """The MARA arm: its MJX model, ids resolved once, and the two drivers."""

    def __init__(self, mj_model: mujoco.MjModel | None = None):
        self.mj_model = load_model() if mj_model is None else mj_model
        m = self.mj_model
        self.joint_ids = np.array([m.joint(n).id for n in JOINTS])
        if m.nq != len(JOINTS) or m.nv != len(JOINTS) or m.nu != 2 * len(JOINTS):
            raise ValueError(
                f"expected a 6-joint arm with a position and a velocity actuator per joint, "
                f"got nq={m.nq} nu={m.nu}"
            )
        self.tcp_site = m.site("tcp").id
        self.flange_body = m.body("motor6_link").id
        self.lower = m.jnt_range[self.joint_ids, 0].copy()
        self.upper = m.jnt_range[self.joint_ids, 1].copy()
        self.timestep = float(m.opt.timestep)

    # ------------------------------------------------------------ MJX, on first use
    # The MJX models and data templates are built the first time a path that needs them
    # runs (the 'mjx' kinematics, the real driver's dynamics): the train driver's default
    # lean pass never does, and importing mujoco.mjx (trimesh, scipy) and putting two
    # models on the device were about 2 s of the train CLI's start-up on a GPU host
    # (benchmarks/NOTES.md section 29). First use may come inside a jit trace: they are
    # built eagerly all the same (concrete arrays, not tracers that would leak).
    @functools.cached_property
    def mjx_model(self) -> mjx.Model:
        """The MJX model (JAX implementation) on this process's first device."""
        with jax.ensure_compile_time_eval():
            return _mjx().put_model(self.mj_model, impl="jax", device=_device())

    @functools.cached_property
    def _data0(self) -> mjx.Data:
        with jax.ensure_compile_time_eval():
            return _mjx().make_data(self.mj_model, impl="jax", device=_device())

    @functools.cached_property
    def num_contacts(self) -> int:
        """Contact slots of MJX's collision pass (the listed pairs' manifolds)."""
        return int(self._data0._impl.contact.dist.shape[0])

    @functools.cached_property
    def _dynamics(self) -> dict[str, tuple[mjx.Model, mjx.Data]]:
        """contacts -> the real driver's dynamics model and data template: 'physical' the
        full model, 'detect' the same with contacts disabled."""
        free = copy.deepcopy(self.mj_model)
        free.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
        mjx = _mjx()
        with jax.ensure_compile_time_eval():
            detect = (
                mjx.put_model(free, impl="jax", device=_device()),
                mjx.make_data(free, impl="jax", device=_device()),
            )
        return {"physical": (self.mjx_model, self._data0), "detect": detect}

    # ------------------------------------------------------------------ poses
    def _pose(self, d: mjx.Data, collided: jax.Array) -> ArmPose:
        """TCP pose and its positional Jacobian of a posed `d`."""
        tcp_pos = d.site_xpos[self.tcp_site]
        tcp_quat = quat_canonical(d.xquat[self.flange_body])
        # Revolute joints: column i of J_pos is axis_i x (p_tcp - anchor_i).
        jac = jnp.cross(d.xaxis, tcp_pos[None, :] - d.xanchor).T
        return ArmPose(tcp_pos, tcp_quat, jac, collided)

    def _penetrating(self, d: mjx.Data) -> jax.Array:
        return jnp.any(d._impl.contact.dist < 0.0) if self.num_contacts else jnp.array(False)

    def pose(self, q: jax.Array, collide: bool = True) -> ArmPose:
        """Kinematics, and collision detection unless `collide` is False (then `collided`
        is False), at joint positions q (6,). Collision costs about 15x kinematics."""
        with jax.named_scope("kinematics"):
            d = _mjx().kinematics(self.mjx_model, self._data0.replace(qpos=q))
        if not collide:
            return self._pose(d, jnp.array(False))
        with jax.named_scope("collision"):
            d = _mjx().collision(self.mjx_model, d)
        return self._pose(d, self._penetrating(d))

    # ---------------------------------------------------------------- drivers
    def pose_with(self, q: jax.Array, kinematics: str, collide: bool = True) -> ArmPose:
        """`pose(q, collide)` through MJX ('mjx'), the lean pass ('lean', envs/lean.py) or
        its scalar form ('fused', envs/fused_pose.py)."""
        if kinematics == "lean":
            return self.lean.pose(q, collide)
        if kinematics == "fused":
            return arm_pose(self.lean, q, collide)
        return self.pose(q, collide)

    @functools.cached_property
    def lean(self) -> LeanArm:
        """The lean pose-and-collision pass of this model (mara_mjx.envs.lean)."""
        return LeanArm.from_model(self.mj_model)

    @functools.cached_property
    def dynamics(self) -> Dynamics:
        """The lean physics step of this model (mara_mjx.envs.dynamics)."""
        return Dynamics.from_model(self.mj_model)

    def train_step(
        self, q: jax.Array, command: jax.Array, control_dt: float, kinematics: str = "mjx"
    ) -> tuple[jax.Array, jax.Array, ArmPose]:
        """Teleport to `command` (already inside the joint box). Returns q', qvel', pose."""
        qvel = (command - q) / control_dt
        return command, qvel, self.pose_with(command, kinematics)

    def dynamics_model(self, contacts: str) -> mjx.Model:
        """The MJX model of the real driver's dynamics: contacts 'physical' (the full
        model) or 'detect' (contacts disabled; the lean step reads its fields too). A
        randomised env edits a copy of it per env."""
        return self._dynamics[contacts][0]

    def real_step(
        self,
        q: jax.Array,
        qvel: jax.Array,
        ref: jax.Array,
        command: jax.Array,
        velocity: jax.Array,
        n_substeps: int,
        model: mjx.Model | None = None,
        contacts: str = "physical",
        kinematics: str = "mjx",
    ) -> tuple[jax.Array, jax.Array, jax.Array, ArmPose]:
        """Servo toward `command` for n_substeps physics steps. Returns q', qvel', ref', pose.

        The pose's `collided` is true if any substep started in penetration or the final
        pose penetrates. `model`: the dynamics model (None: `dynamics_model(contacts)`; a
        randomised env passes its per-env masses, damping, gains, ... on that model).
        `contacts`: 'physical' or 'detect' (the module docstring); `kinematics`, with
        'detect': 'lean' (the pose pass of `pose_with` and the step of dynamics.py, which
        reads its masses, gains, ... from `model`) or 'mjx' (`pose` and `mjx.step`).
        """
        physical = contacts == "physical"
        lean = not physical and kinematics in ("lean", "fused")
        model = self.dynamics_model(contacts) if model is None else model
        max_move = velocity * self.timestep

        def substep(carry, _):
            physics, ref, hit = carry
            move = jnp.clip(command - ref, -max_move, max_move)
            ref = ref + move
            ctrl = jnp.concatenate([ref, move / self.timestep])  # [ref, ref_vel]
            if lean:
                start = physics[0]
                physics = self.dynamics.step(model, *physics, ctrl)
            else:
                start = physics.qpos
                physics = _mjx().step(model, physics.replace(ctrl=ctrl))
                if physical:  # the contacts of this substep's start pose
                    hit = hit | self._penetrating(physics)
            return (physics, ref, hit), start

        physics = (q, qvel) if lean else self._dynamics[contacts][1].replace(qpos=q, qvel=qvel)
        with jax.named_scope("dynamics"):
            (physics, ref, hit), starts = jax.lax.scan(
                substep, (physics, ref, jnp.array(False)), None, length=n_substeps
            )
        q, qvel = physics if lean else (physics.qpos, physics.qvel)
        if physical:
            pose = self.pose(q)
        else:
            with jax.named_scope("substep_collision"):
                poses = jnp.concatenate([starts, q[None]])
                hit = jnp.any(jax.vmap(lambda x: self.pose_with(x, kinematics).collided)(poses))
            pose = self.pose_with(q, kinematics, collide=False)
        return q, qvel, ref, pose._replace(collided=pose.collided | hit)

    # ------------------------------------------------------------ rendering
    def mj_data(self, q: np.ndarray, target_pos=None, target_quat=None) -> mujoco.MjData:
        """A C MuJoCo MjData at pose q with the target marker placed (host side)."""
        d = mujoco.MjData(self.mj_model)
        d.qpos[:] = np.asarray(q)
        if target_pos is not None:
            d.mocap_pos[0] = np.asarray(target_pos)
        if target_quat is not None:
            d.mocap_quat[0] = np.asarray(target_quat)
        mujoco.mj_forward(self.mj_model, d)
        return d
