"""The policy's parametrisation: how the network's output becomes the env's joint targets.

    PolicyConfig    joint deltas (relative_actions), the task-space step, the servo-speed
                    squash, the IK residual and its rules (gates, wrap, orient-first, the
                    finish and its guard), which observation entries the networks see
    resolve(policy, env) -> the PolicyConfig with quat_index set from the env's layout

One config used alike by training (`mara_mjx.ppo.train`, whose network adds the
training-only rules train_ik_gate_roll and train_ik_orient_loose), by the saved policy
(`mara_mjx.ppo.policy.make_policy`: evaluation, play, the gymnasium adapter) and by the
exported file (`mara_mjx.cli.export`); `mara_mjx.ppo.networks.make_network` is where it
becomes an ActorCritic. It is `TrainConfig.policy` (`mara_mjx.ppo.config`); its flags
are the train CLI's `--relative_actions`, `--ik_finish`, ... (also `--ppo.ik_finish`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal

from mara_mjx.config import ConfigMixin as _ConfigMixin
from mara_mjx.config import check_range as _check_range
from mara_mjx.config import is_int as _is_int

IK_PRIORS = ("", "features", "residual")


MAX_PLAN_STEPS = 64
"""The most imagined steps PolicyConfig.plan_steps allows (each costs a policy call)."""
MAX_COMMIT_RAD = 0.5
"""The widest arrival tolerance PolicyConfig.commit_rad allows (rad per joint)."""
MAX_PLAN_STARTS = 32
"""The most other starting postures PolicyConfig.plan_starts allows (each costs
PLAN_START_STEPS policy calls per decision)."""
PLAN_START_STEPS = 32
"""Imagined train-driver steps from each of PolicyConfig.plan_starts' postures (twice the
recipes' plan_steps: from a far posture 16 steps often end short of the target; measured,
benchmarks/NOTES.md section 47)."""
PLAN_KEEP_MM = 1.0
"""PolicyConfig.plan_starts keeps the policy's own landing when it is within this (mm on
every position axis, deg of orientation), and takes another start's only when that one is."""
PLAN_CLEAR_MM = 2.0
"""PolicyConfig.plan_starts takes another start's landing only where the nominal arm keeps
this clearance (mm, to every contact pair the env checks; or the clearance it has now,
where that is less) at the landing and along the servos' path to it (every joint at the
same speed), checked at PLAN_PATH_POINTS points: a restart can converge on a branch folded
back onto the arm, or one whose path sweeps the gripper through the base (measured,
benchmarks/NOTES.md section 48)."""
PLAN_PATH_POINTS = 16
"""Points of the servos' path at which PLAN_CLEAR_MM is checked (the landing the last)."""
PLAN_RESTART_GROUP = 32
"""PolicyConfig.plan_starts restarts the rows of a batch whose own landing misses this
many at a time (policy.restarted_landing): the cost of a decision follows the rows that
miss, not the batch."""


@dataclasses.dataclass(frozen=True)
class PolicyConfig(_ConfigMixin):
    """How the Gaussian mean is formed from the actor's output (and the observation); the
    env, its action space and its reward are the same whatever these are. Defaults are
    baselines' (the actor's output is the absolute joint target); see `PRESETS`. No preset
    sets task_space_actions, max_joint_step or hidden_obs (nor ik_prior='features'); they
    stay for the measured studies that use them (benchmarks/NOTES.md sections 19-20, the
    configs of benchmarks/results/random_target/) and the exported file carries the last
    two (mara_mjx/deploy/onnx_policy.py)."""

    relative_actions: bool = False
    """The Gaussian mean is the current joint positions (the observation's first entries)
    plus the actor's output, instead of the actor's output alone (baselines). The env's
    action is still absolute joint targets; only the policy's parametrisation changes."""
    task_space_actions: bool = False
    """With relative_actions: the actor's output is a TCP displacement (position, then
    rotation, world frame) that one damped-least-squares step through the nominal arm's
    Jacobian at the observed joints turns into the joint displacement
    (mara_mjx.envs.task_space), instead of the joint displacement itself. The Gaussian, its
    noise and the env's action stay in joint space; reaching a pose becomes a nearly linear
    function of the observation in every arm posture (benchmarks/NOTES.md section 20).
    MARA arms only (6 joints, q first in the observation)."""
    max_joint_step: float = 0.0
    """With relative_actions, > 0: the most each joint target may differ from the observed
    joint position (rad per control step). The mean's displacement is squashed to
    m tanh(delta / m) and the rollout's sampled actions are clipped to q +- m (the log-prob
    is the unclipped sample's, as for any clipped action). For policies meant for the real
    driver, whose servos move at most velocity x control_dt per step (0.3 rad/s x 0.05 s =
    0.015 rad): a policy trained on the teleporting train driver otherwise learns to jump
    through obstacles and far across joint space (benchmarks/NOTES.md section 20). 0: off."""
    ik_prior: Literal["", "features", "residual"] = ""
    """An inverse-kinematics step as prior knowledge of the arm (MARA arms; q then e first
    in the observation, quat_err where the task has it): dq = one bounded damped-least-
    squares step of the nominal arm toward the pose the observation reports
    (mara_mjx.envs.task_space.pose_step, computed from the observation alone, no
    gradient). 'features': tanh(dq / s) at three scales s (0.002, 0.03, 0.3 rad) are extra
    inputs of both networks, so that "turn the tool onto the target while keeping its
    position" is a nearly linear function of the inputs in every arm posture. 'residual'
    (needs relative_actions): the features, and dq added to the mean's joint displacement,
    so the actor learns a correction to the IK step (residual policy learning: Silver et
    al. 2018, Johannink et al. 2019). The env, its action and its reward are unchanged.
    '': off."""
    ik_gate: float = 0.0
    """m, with ik_prior='residual', > 0: the actor's learnt correction is multiplied by
    tanh(|e| / s) (s this value, e the observed TCP position error: 0.76 at |e| = s,
    0.1 at s / 10), so as the TCP closes on the target position the IK step alone moves
    the arm: a Newton step of the whole pose,
    whose error falls to 0 from the branch the policy has taken, instead of settling
    where the correction's own bias balances it (benchmarks/NOTES.md section 24). Far
    from the target the residual is unchanged. 0: off."""
    ik_wrap: bool = False
    """With ik_prior: the IK step takes the last joint (the flange's roll, a full turn of
    range) the long way round where, within 2 cm of the target, the short way would end
    past its limit (envs/task_space.pose_step wrap_last): the same tool pose, which a
    local step would otherwise never reach (benchmarks/NOTES.md section 24)."""
    ik_gate_wrap: bool = False
    """With ik_gate and ik_wrap: the gate is also closed (the IK step alone) while the IK
    step turns the last joint the long way round, a manoeuvre of up to 2 pi over tens of
    steps that a correction learnt mostly elsewhere otherwise undoes halfway (a limit
    cycle measured in benchmarks/NOTES.md section 24); with ik_orient_first, also where
    the IK step's flag asks for it (train_ik_gate_roll's rolls; the deployed policy's
    last 6 cm, envs/task_space.ORIENT_FIRST_NEAR)."""
    ik_orient_first: bool = False
    """With ik_prior and an orientation in the task: the IK step turns the tool onto the
    target before the TCP closes in, as a peg is aligned before insertion (the TCP keeps
    0.5 m per rad of rotation left after the step's own from the target, and 1 cm until
    the tool is within 0.02 rad); with ik_wrap it decides the flange's long way round from
    the roll still to turn, at any distance, and holds the TCP's position while it rolls;
    with ik_gate_wrap, within 6 cm of the target the correction is off and the IK step
    alone makes the last approach (envs/task_space.pose_step orient_first;
    benchmarks/NOTES.md sections 26-27). For an evaluation that stops at the first step
    within a position tolerance, as the paper's; the env is unchanged.
    train_ik_orient_loose (on by default) keeps the hold and the 6-cm zone out of
    training. Needs ik_prior='residual' with ik_gate_wrap (the zone acts through its
    gate)."""
    train_ik_orient_loose: bool = True
    """With ik_orient_first, during training only: the IK step's loose form, without the
    1-cm hold until the tool is aligned and without the IK-alone zone near the target
    (the form every orient-first policy so far was trained with; a config saved before
    the field existed reads true). The exploration noise keeps the tool about a degree
    off the target, so under a standoff that lasts until 0.02 rad the sampled TCP does
    not close in and little is learnt (benchmarks/NOTES.md section 27: trained with an
    earlier strict form, a standoff of 0.5 m per rad down to 0.02 rad, 17 of 20 seed-runs
    reached 5 mm in at most 3 of 10 episodes; false, training with the present deployed
    form, is unmeasured). The saved, deterministic policy always runs the deployed form,
    which enters the paper's 5 mm box with the tool turned. No effect without
    ik_orient_first."""
    train_ik_gate_roll: bool = False
    """During training only, with ik_gate_wrap and ik_orient_first: the gate is also closed
    while the IK step's flange roll still exceeds one step (0.25 rad), so that the second
    half of a long way round (where the short and the long way agree and the wrap flag is
    off) is the IK step's alone. The policy that training saves (evaluate, play, the
    gymnasium adapter) runs without it. Measured (benchmarks/NOTES.md section 26, 5 seeds
    per Orient task): the two MARACollisionOrient seeds that cycled on the far side of the
    base reach the pose; kept at inference too, 3 MARAOrient seeds in 5 missed 1-2
    episodes in 10, without it at inference all 10 seed-runs reached 10/10 within 2 deg."""
    ik_finish: float = 0.0
    """m, > 0: the saved (deterministic) policy of a position task ends its reach with the
    IK step alone: within this distance of the target position its joint targets are
    q + envs/task_space.finish_step(q, e), a position-only damped-least-squares step
    toward 1 cm short of the target, then onto it. For an evaluation that stops at the
    first step within a position tolerance, as the paper's: the learnt policy's own last
    step lands a few millimetre off (MARA `default`: up to 3.73 mm per axis on 10 seeds;
    with 0.06: worst 0.25 mm on 15 fresh seeds, benchmarks/NOTES.md sections 27-28). The
    trainer's network and the env are unchanged (training is the same with or without
    it). A learnt step that would jump into the zone stops just inside its edge
    (task_space.stop_outside). Needs relative_actions, no max_joint_step, and a MARA
    observation without an orientation (on the Orient tasks ik_orient_first's 6-cm zone
    is the same finish for the whole pose). Export: .npz keeps it (mara_mjx/deploy/ik_numpy.py);
    .onnx needs --drop_ik_finish (the learnt policy alone). 0: off."""
    collision_guard_mm: float = 0.0
    """mm, > 0: the saved (deterministic) policy never commands a posture whose nominal arm
    comes closer than this to a contact (a link, the gripper, the base or the table): a
    step that would is shortened along its way until it keeps that clearance (or the
    clearance the arm already has, if less), and the policy chooses again from there
    (envs/clearance.keep_clear). Measured on MARACollisionOrient's default, 16 seeds: the
    one seed whose learnt step put a finger 13-21 mm into the table 150 mm before the
    target stops colliding, every reach unchanged (benchmarks/NOTES.md section 38). The
    trainer's network and the env are unchanged (training is the same with or without
    it). Needs relative_actions and a MARA arm. Export: .onnx traces it; .npz refuses it.
    0: off."""
    plan_steps: int = 0
    """Deployed only, > 0: the saved (deterministic) policy commands the posture it would
    reach in this many steps of the train driver from the observed joints, imagined on
    the nominal arm (each imagined step: the policy's targets clipped to the joint
    limits, then the observation there: q, e and quat_err from the nominal chain's TCP,
    the TCP velocity of a jump of one control period, EnvConfig.control_dt; no contact
    check), instead of its first step. A policy trained on the train driver's jumps has
    planned its reach only for the postures jumps visit; a servo-driven arm passes
    through others, where its commands wander into contacts (the real-driver misses of
    the random-target tasks: collisions, resets and again, benchmarks/NOTES.md section
    42). Commanding the imagined landing lets the servos carry out the policy's own
    plan; near the target the plan and the first step agree. Training is unchanged.
    Needs a MARA arm and the default control period. Export: .onnx traces it; .npz
    refuses it. 0: off."""
    plan_starts: int = 0
    """Deployed only, > 0 (needs plan_steps): when the policy's own imagined landing ends
    farther than PLAN_KEEP_MM from the target (on any position axis, mm, or in orientation,
    deg), the policy also imagines PLAN_START_STEPS train-driver steps toward the same
    target from each of this many other starting postures (fixed, the same for every
    decision: uniform within 0.8 x the joint ranges, numpy's default_rng(0), so the first
    K of a larger set are the K of a smaller one), and commands, of the landings within
    PLAN_KEEP_MM that keep PLAN_CLEAR_MM from every contact on the servos' path to them,
    the one with the shortest path (the smallest largest joint move); where none is, the
    other wrist branch of its own landing solved by the IK step alone, if that reaches
    and is clear so; else its own. A trained policy can
    lead the arm onto a branch where the wrist stops at its limit short of a pose near the
    region's edge, and stay there (a fixed point of the policy: the random-target tasks'
    training misses, benchmarks/NOTES.md section 43); from another start the same policy
    takes another branch. This is inverse kinematics' random restarts with the policy as
    the solver. A decision whose own landing misses costs plan_steps + plan_starts x
    PLAN_START_STEPS policy calls (the starts imagined side by side, for the rows of a
    batch that miss only, PLAN_RESTART_GROUP at a time); measured, 16 starts:
    benchmarks/NOTES.md section 49 (the preset random_target_orient_plan). Training is
    unchanged. Needs a MARA arm and the default control period. Export: .onnx traces it;
    .npz refuses it. 0: off."""
    commit_rad: float = 0.0
    """Deployed only, rad, > 0: the deployed policy holds each command until the arm has
    carried it out, and only then chooses again: the joint targets sent last are sent
    again while the observed joints are not all within this distance of them and the
    arm still moves (some joint moved more than deploy/numpy_policy.COMMIT_STALL_RAD,
    0.002 rad, in the last control period); otherwise the policy's new targets, clipped
    to the joint limits (deploy/numpy_policy.committed, the one rule of the evaluation
    loop, `play` and the robot-side runner; applied around the policy, not inside it).
    On the train driver every command is carried out within one step, so nothing
    changes there (but for a colliding command, which the train driver answers with the
    reset pose: it is sent once more). On servos, where a command takes many steps, a
    policy (with plan_steps, its imagined landing) asked again at every posture on the
    way can switch between two solutions of the same pose (elbow up and elbow down)
    where they meet and stay there, commanding one then the other; held commands cross
    that posture once, and the servos then do what the train driver does (a CPU screen,
    benchmarks/NOTES.md section 43). Needs a MARA arm. Export: the file's metadata
    carries it; the runner and `evaluate policy.onnx` apply it around the graph. 0: off."""
    hidden_obs: tuple[int, ...] = ()
    """Observation indices that neither network sees (set to 0 after normalisation), e.g.
    9 10 11 for the TCP velocity of MARA/MARACollision (13 14 15 for the Orient tasks)."""
    canonical_quat: bool = False
    """The networks read the observation's quaternion error (the env's `quat_err` block,
    (w, x, y, z)) with its sign canonicalised to w >= 0 before normalisation. q and -q are
    the same rotation; the env's quat_err flips between them at the goal of the Orient
    tasks (the TCP quaternion is made w >= 0 and the target has w = 0), which flips the
    sign of the rotation-error vector the policy must steer by (benchmarks/NOTES.md,
    section 11). A re-encoding of the same observation, not a change of the env."""
    quat_index: int = -1
    """Where the quaternion block starts in the observation; set by `for_env` from the env's
    `observation_layout` (make_train and the train CLI do it), -1 where the env has none."""

    def __post_init__(self):
        for name in ("relative_actions", "task_space_actions", "canonical_quat"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if not isinstance(self.hidden_obs, tuple) or not all(
            _is_int(i) and i >= 0 for i in self.hidden_obs
        ):
            raise ValueError(
                f"hidden_obs={self.hidden_obs!r} must be a tuple of observation indices >= 0"
            )
        if self.task_space_actions and not self.relative_actions:
            raise ValueError(
                "task_space_actions=true needs relative_actions=true (the TCP displacement is "
                "taken from the observed joints); set both, or task_space_actions=false"
            )
        if self.ik_prior not in IK_PRIORS:
            raise ValueError(f"ik_prior={self.ik_prior!r} is not valid; choose one of {IK_PRIORS}")
        if self.ik_prior == "residual" and not self.relative_actions:
            raise ValueError(
                "ik_prior='residual' needs relative_actions=true (the IK step is added to the "
                "displacement from the observed joints); set both, or ik_prior='features'"
            )
        self._check_ik_rules()
        _check_range("max_joint_step", self.max_joint_step, 0.0, math.pi)
        _check_range("collision_guard_mm", self.collision_guard_mm, 0.0, 100.0)
        if not _is_int(self.plan_steps) or not 0 <= self.plan_steps <= MAX_PLAN_STEPS:
            raise ValueError(
                f"plan_steps must be an int in [0, {MAX_PLAN_STEPS}] (imagined train-driver "
                f"steps; 0: off), got {self.plan_steps!r}"
            )
        if not _is_int(self.plan_starts) or not 0 <= self.plan_starts <= MAX_PLAN_STARTS:
            raise ValueError(
                f"plan_starts must be an int in [0, {MAX_PLAN_STARTS}] (other starting "
                f"postures of the plan; 0: off), got {self.plan_starts!r}"
            )
        if self.plan_starts and not self.plan_steps:
            raise ValueError(
                f"plan_starts={self.plan_starts} imagines the plan from other postures and "
                "needs plan_steps > 0; set plan_steps (e.g. 16), or plan_starts=0"
            )
        _check_range("commit_rad", self.commit_rad, 0.0, MAX_COMMIT_RAD)
        if self.collision_guard_mm > 0.0 and not self.relative_actions:
            raise ValueError(
                f"collision_guard_mm={self.collision_guard_mm} shortens the step from the "
                "observed joints and needs relative_actions=true; set it, or collision_guard_mm=0"
            )
        if self.max_joint_step > 0.0 and not self.relative_actions:
            raise ValueError(
                f"max_joint_step={self.max_joint_step} needs relative_actions=true (the limit "
                "is around the observed joints); set both, or max_joint_step=0"
            )
        if not _is_int(self.quat_index) or self.quat_index < -1:
            raise ValueError(f"quat_index must be an int >= -1, got {self.quat_index!r}")

    def _check_ik_rules(self) -> None:
        """The IK residual's rules each need the ones they build on."""
        _check_range("ik_gate", self.ik_gate, 0.0, math.inf)
        if self.ik_gate > 0.0 and self.ik_prior != "residual":
            raise ValueError(
                f"ik_gate={self.ik_gate} gates the correction of ik_prior='residual', but "
                f"ik_prior={self.ik_prior!r}; set ik_prior='residual', or ik_gate=0"
            )
        if self.ik_gate_wrap and not (self.ik_gate > 0.0 and self.ik_wrap):
            raise ValueError(
                f"ik_gate_wrap=true closes the gate of ik_gate while ik_wrap turns the last "
                f"joint, but ik_gate={self.ik_gate}, ik_wrap={self.ik_wrap}; set both "
                f"(ik_gate > 0, ik_wrap=true), or ik_gate_wrap=false"
            )
        if self.train_ik_gate_roll and not (self.ik_gate_wrap and self.ik_orient_first):
            raise ValueError(
                f"train_ik_gate_roll=true extends the gate closing of ik_gate_wrap with "
                f"ik_orient_first, but ik_gate_wrap={self.ik_gate_wrap}, "
                f"ik_orient_first={self.ik_orient_first}; set both, or train_ik_gate_roll=false"
            )
        if self.ik_orient_first and not (self.ik_prior == "residual" and self.ik_gate_wrap):
            raise ValueError(
                "ik_orient_first=true changes the IK step of ik_prior='residual' and leaves "
                "the last approach to it through ik_gate_wrap's gate, but "
                f"ik_prior={self.ik_prior!r}, ik_gate_wrap={self.ik_gate_wrap}; set "
                "ik_prior='residual' with ik_gate > 0, ik_wrap and ik_gate_wrap (as "
                "--preset orient_first), or ik_orient_first=false"
            )
        _check_range("ik_finish", self.ik_finish, 0.0, math.inf)
        if self.ik_finish > 0.0 and not self.relative_actions:
            raise ValueError(
                f"ik_finish={self.ik_finish} replaces the joint displacement near the target "
                "and needs relative_actions=true; set it, or ik_finish=0"
            )
        if self.ik_finish > 0.0 and self.max_joint_step > 0.0:
            raise ValueError(
                f"ik_finish={self.ik_finish} takes IK steps of up to 0.25 rad per joint, which "
                f"max_joint_step={self.max_joint_step} would squash; set one of them to 0"
            )
        if self.ik_wrap and not self.ik_prior:
            raise ValueError(
                "ik_wrap=true changes the IK step of ik_prior, which is off; "
                "set ik_prior='features' or 'residual', or ik_wrap=false"
            )


def check_overrides(plan_steps: Any, plan_starts: Any, commit_rad: Any) -> None:
    """ValueError unless each is an override of its PolicyConfig field as the evaluations
    take it: -1 (as trained or exported), or a valid value (0: off)."""
    if not _is_int(plan_steps) or not -1 <= plan_steps <= MAX_PLAN_STEPS:
        raise ValueError(
            f"plan_steps must be -1 (as trained) or in [0, {MAX_PLAN_STEPS}], got {plan_steps!r}"
        )
    if not _is_int(plan_starts) or not -1 <= plan_starts <= MAX_PLAN_STARTS:
        raise ValueError(
            f"plan_starts must be -1 (as trained) or in [0, {MAX_PLAN_STARTS}], got {plan_starts!r}"
        )
    try:
        if commit_rad != -1.0:
            _check_range("commit_rad", commit_rad, 0.0, MAX_COMMIT_RAD)
    except ValueError:
        raise ValueError(
            f"commit_rad must be -1 (as trained) or a number in [0, {MAX_COMMIT_RAD}], "
            f"got {commit_rad!r}"
        ) from None


def plan_overrides(plan_steps: int | None, plan_starts: int | None) -> dict[str, int]:
    """The PolicyConfig fields that the plan's overrides (evaluate's, export's) set on a
    policy (None: as trained; other values as given, for PolicyConfig to check):
    plan_steps and plan_starts, and plan_starts 0 where plan_steps is 0 and plan_starts
    is not given (no plan, nothing to restart)."""
    plan = {}
    if plan_steps is not None:
        plan["plan_steps"] = int(plan_steps)
        if plan_steps == 0:
            plan["plan_starts"] = 0
    if plan_starts is not None:
        plan["plan_starts"] = int(plan_starts)
    return plan


def check_plan_period(plan_steps: int, env: Any) -> None:
    """ValueError where a policy with `plan_steps` (> 0) would run on an env whose control
    period is not the default its imagined train-driver steps assume."""
    from mara_mjx.envs.base import EnvConfig

    dt = getattr(getattr(env, "config", None), "control_dt", EnvConfig.control_dt)
    if plan_steps and dt != EnvConfig.control_dt:
        raise ValueError(
            f"plan_steps={plan_steps} imagines the train driver at the default control "
            f"period ({EnvConfig.control_dt} s); this env's control_dt is {dt}; set "
            "plan_steps=0"
        )


def resolve(policy: PolicyConfig, env: Any) -> PolicyConfig:
    """`policy` for `env`: `quat_index` from the env's `observation_layout` (a list of
    {name, start, stop, ...}; -1 where it has no quat_err or nothing reads it), and
    ik_wrap, ik_gate_wrap, ik_orient_first and train_ik_gate_roll cleared for an env
    without quat_err (no tool roll to wrap, nothing to turn first). ValueError where the
    env cannot carry the parametrisation (the IK step needs a MARA arm's observation; the
    position finish a task without an orientation; hidden_obs entries it has)."""
    layout = getattr(env, "observation_layout", None) or []
    starts = [int(part["start"]) for part in layout if part.get("name") == "quat_err"]
    index = starts[0] if ((policy.canonical_quat or policy.ik_prior) and starts) else -1
    where = {part.get("name"): int(part["start"]) for part in layout}
    arm = where.get("q") == 0 and where.get("e") == 6 and getattr(env, "action_size", 6) == 6
    for option, value, off in (
        ("ik_prior", policy.ik_prior, "''"),
        ("ik_finish", policy.ik_finish, "0"),
        ("collision_guard_mm", policy.collision_guard_mm, "0"),
        ("plan_steps", policy.plan_steps, "0"),
        ("plan_starts", policy.plan_starts, "0"),
        ("commit_rad", policy.commit_rad, "0"),
    ):
        if value and not arm:
            raise ValueError(
                f"{option}={value!r} needs a MARA arm's observation (q at 0, e at 6) "
                f"and 6 joint actions; this env has neither; set {option}={off}"
            )
    check_plan_period(policy.plan_steps, env)
    size = getattr(env, "observation_size", None)
    if size is not None and any(i >= size for i in policy.hidden_obs):
        raise ValueError(
            f"hidden_obs={tuple(policy.hidden_obs)} names entries past this env's "
            f"observation ({size} entries: 0-{size - 1}); choose indices below {size}"
        )
    if policy.ik_finish > 0.0 and starts:
        raise ValueError(
            f"ik_finish={policy.ik_finish} moves the TCP onto the target position and leaves "
            "the tool's orientation to chance, but this task has one (quat_err); use "
            "--preset orient_first (its last 6 cm are the IK step of the whole pose), or "
            "ik_finish=0"
        )
    resolved = policy if index == policy.quat_index else policy.replace(quat_index=index)
    if not starts and resolved.ik_wrap:
        resolved = resolved.replace(
            ik_wrap=False, ik_gate_wrap=False, ik_orient_first=False, train_ik_gate_roll=False
        )
    return resolved
