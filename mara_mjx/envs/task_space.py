"""Task-space actions: a TCP displacement mapped to joint targets through the arm's Jacobian.

The env's action stays what the spec says, absolute joint targets (rad). A policy may
instead *parametrise* its joint targets by a TCP displacement (PolicyConfig.task_space_actions):
its output u (6,) is read as a small TCP move, position then rotation, in the world frame,

    dx = (u[:3] * POSITION_SCALE, u[3:] * ROTATION_SCALE)      (m, rad)

and turned into joint targets by one damped-least-squares step at the observed joints q,

    q_target = q + J(q)^T (J(q) J(q)^T + DAMPING^2 I)^-1 dx

with J the TCP's geometric Jacobian (6, 6) of the *nominal* arm (envs/chain.py: the
policy knows the arm's drawing, not a randomised one's true geometry; the same q the
policy observes). This is the resolved-rate / operational-space parametrisation of
robosuite's OSC controllers and of classic visual servoing: "move the tool toward the
target and turn it onto the target's orientation" becomes a nearly linear function of
the observation (dx = -k (e, rotation error)), whatever the arm's posture, so the position
and the orientation each have their own action directions even where joint space makes
them hard to tell apart (benchmarks/NOTES.md section 20). Near a singularity the damping
keeps the step bounded (|dq| <= |dx| / (2 DAMPING)).

    q_target = task_to_joint(q, u)          # (..., 6), (..., 6) -> (..., 6) rad

The same step toward the target pose that an observation reports (`pose_step`: the TCP
error e and the orientation error quat_err, read from the observation) is a Newton /
resolved-rate step of inverse kinematics, which a policy may take as an input feature or
as the base its output corrects (PolicyConfig.ik_prior, residual-policy learning):

    dq = pose_step(q, e, quat_err)          # (..., 6) rad, bounded

With wrap_last (and an orientation), the last joint (the tool flange's roll, range a
full turn) is taken the long way round where the short way would end past its limit: the
same tool pose, 2 pi of that joint away, as a local step would otherwise stop at the
limit (benchmarks/NOTES.md section 24). With orient_first the tool is turned onto the
target before the TCP closes in, and the last approach is the IK step's alone (for an
evaluation that stops at the first step within a position tolerance; training runs its
loose form; benchmarks/NOTES.md sections 26-27). On a position task, `finish_step` is the
last approach of a deployed policy's IK finish (PolicyConfig.ik_finish): the IK step alone,
first to 1 cm short of the target, then onto it (benchmarks/NOTES.md section 28).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.envs.chain import Chain
from mara_mjx.envs.geometry import quat_canonical, quat_conj, quat_mul
from mara_mjx.envs.linalg import spd_solve

POSITION_SCALE = 0.1
"""m of TCP motion per unit of the policy's position output."""
ROTATION_SCALE = 0.5
"""rad of TCP rotation per unit of the policy's rotation output."""
DAMPING = 0.02
"""Damped-least-squares damping (m or rad; J J^T + DAMPING^2 I)."""
MAX_POSITION_STEP = 0.05
"""pose_step: the most TCP displacement (m) asked for in one step."""
MAX_ROTATION_STEP = 0.25
"""pose_step: the most TCP rotation (rad) asked for in one step."""
MAX_STEP_JOINT = 0.25
"""pose_step: the most any joint moves (rad) in one step (the step is scaled down whole)."""
ORIENT_FIRST_STANDOFF = 0.5
"""pose_step(orient_first=True): m of TCP distance kept from the target per rad of rotation
still to turn after the step's own (MAX_ROTATION_STEP): 8.7 mm per degree."""
ORIENT_FIRST_HOLD = 0.01
"""pose_step(orient_first=True, loose=False): m, the TCP also stays at least this far from
the target until the tool is within ORIENT_FIRST_ALIGNED. 1 cm is more than the diagonal
of the paper's 5 mm box (8.7 mm): the TCP waits outside the box while the last degrees
turn, then enters in one Newton step of the whole pose."""
ORIENT_FIRST_ALIGNED = 0.02
"""pose_step(orient_first=True, loose=False): rad (1.15 deg), the angle below which the TCP
closes in with no standoff. Without the hold (the loose rule, training's), the last
rotation step and the approach converge together and the TCP enters the box with the
tool's second-order error of about a degree (benchmarks/NOTES.md sections 26-27)."""
ORIENT_FIRST_NEAR = 0.06
"""pose_step_wrapping(orient_first=True, loose=False): m, within this distance of the target
position the flag is on (PolicyConfig.ik_gate_wrap then closes the residual's gate: the IK
step alone): a full position step (MAX_POSITION_STEP) plus ORIENT_FIRST_HOLD, so the
last approach into the tolerance is the Newton step's, not the learnt correction's
(whose tenth, left by ik_gate at 1 cm, turned the tool by about a degree on entry;
benchmarks/NOTES.md section 27)."""
FINISH_HOLD = ORIENT_FIRST_HOLD
"""finish_step: m, the IK step aims this far short of the target (on the line to it) until
the TCP is within FINISH_WITHIN x FINISH_HOLD, then at the target itself."""
FINISH_WITHIN = 1.2
"""finish_step: the aim moves onto the target within this multiple of FINISH_HOLD."""
STOP_OUTSIDE_ITERS = 12
"""stop_outside: bisection halvings (the TCP stops within 2^-12 of the step past the edge)."""
WRAP_NEAR = 0.02
"""pose_step(wrap_last=True): m, the TCP distance within which the last joint may be
taken the long way round (farther, the full Newton step is no estimate of where it ends)."""


@functools.lru_cache(maxsize=1)
def last_joint_range() -> tuple[float, float]:
    """(lower, upper) of the nominal arm's last joint (rad)."""
    lower, upper = joint_ranges()
    return lower[5], upper[5]


@functools.lru_cache(maxsize=1)
def joint_ranges() -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(lower (6,), upper (6,)) of the nominal arm's joints (rad)."""
    from mara_mjx.envs.arm import load_model

    lo, hi = load_model().jnt_range.T
    return tuple(float(x) for x in lo), tuple(float(x) for x in hi)


def stop_outside(
    q: jax.Array, e: jax.Array, dq: jax.Array, radius: float, iters: int = STOP_OUTSIDE_ITERS
) -> jax.Array:
    """dq (..., 6), shortened where it would take the TCP from outside `radius` (m) of the
    target to deeper inside: to alpha dq, where bisection (`iters` halvings) finds the
    step's way crossing into the zone, so the TCP stops just inside its edge (where the
    IK step takes over on the next step). Elsewhere dq unchanged. A deployed policy's
    guard: its learnt step does not jump into the zone where the IK step alone makes the
    last approach (PolicyConfig.ik_finish, ik_orient_first; benchmarks/NOTES.md section 28).
    The TCP after a step is the nominal arm's at q + alpha dq clipped to the joint limits,
    as the env clips its targets: one forward kinematics per halving."""
    chain = nominal_chain()
    # numpy, not jnp: a jnp constant made while tracing is a traced value, which a loop
    # body may not close over for jax2onnx
    lo6, hi6 = (np.asarray(x, np.float32) for x in joint_ranges())
    step = dq  # the gradient flows through the step itself, not through alpha
    q, e, dq = (jax.lax.stop_gradient(x) for x in (q, e, dq))
    tcp = jnp.vectorize(lambda q1: chain.tcp(q1)[0], signature="(6)->(3)")
    # Batch-first, the loop outermost, its batched values in the carry: jax2onnx exports
    # a fori_loop neither under vmap (no batching rule) nor closing over traced values.
    target = tcp(q) - e

    def outside(alpha, q, dq, target):  # alpha (...,) -> (...,) bool
        after = tcp(jnp.clip(q + alpha[..., None] * dq, lo6, hi6)) - target
        return jnp.sum(jnp.square(after), -1) >= radius**2

    def halve(_, carry):
        lo, hi, q, dq, target = carry
        mid = 0.5 * (lo + hi)
        out = outside(mid, q, dq, target)
        return jnp.where(out, mid, lo), jnp.where(out, hi, mid), q, dq, target

    ones = jnp.ones(q.shape[:-1], q.dtype)
    jumps = (jnp.sum(jnp.square(e), -1) >= radius**2) & ~outside(ones, q, dq, target)
    hi = jax.lax.fori_loop(0, iters, halve, (jnp.zeros_like(ones), ones, q, dq, target))[1]
    alpha = jnp.where(jumps, hi, 1.0)
    return alpha[..., None] * step


@functools.lru_cache(maxsize=1)
def nominal_chain() -> Chain:
    """The kinematic chain of the MARA model in the package's assets (built once)."""
    from mara_mjx.envs.arm import load_model  # arm imports chain (through lean): no cycle

    return Chain.from_model(load_model())


def dls_step(jac: jax.Array, dx: jax.Array, damping: float = DAMPING) -> jax.Array:
    """jac (m, n), dx (m,) -> dq = J^T (J J^T + damping^2 I)^-1 dx (n,). On a CPU backend
    the solve is written out (envs/linalg.py: jaxlib's batched LAPACK LU can deadlock
    XLA's CPU thread pool); elsewhere it is the library's LU (cuSolver on a GPU), as every
    GPU result of this project was trained with."""
    gram = jac @ jac.T + (damping**2) * jnp.eye(jac.shape[0], dtype=jac.dtype)
    # Chosen at trace time by the default backend, so that a GPU program is exactly what
    # it was. (`lax.platform_dependent` would also cover a CPU device on a GPU host, but
    # it changes the GPU program's HLO: a `case` per call, checked by lowering for CUDA.)
    if jax.default_backend() == "cpu":
        return jac.T @ spd_solve(gram, dx)
    return jac.T @ jnp.linalg.solve(gram, dx)


def task_to_joint(q: jax.Array, u: jax.Array) -> jax.Array:
    """q (..., 6) rad observed joints, u (..., 6) policy output -> joint targets (..., 6)."""
    chain = nominal_chain()
    scale = jnp.array([POSITION_SCALE] * 3 + [ROTATION_SCALE] * 3, jnp.float32)

    def one(q1: jax.Array, u1: jax.Array) -> jax.Array:
        jac = chain.jacobian(jax.lax.stop_gradient(q1))
        return q1 + dls_step(jax.lax.stop_gradient(jac), u1 * scale)

    return jnp.vectorize(one, signature="(6),(6)->(6)")(q, u)


def rotation_vector(quat: jax.Array) -> jax.Array:
    """(..., 4) (w, x, y, z) unit quaternion -> (..., 3) axis * angle (rad), angle in [0, pi]
    (q and -q give the same vector)."""
    quat = quat_canonical(quat)
    w, v = quat[..., 0], quat[..., 1:]
    n = jnp.linalg.norm(v, axis=-1)
    small = n < 1e-6
    scale = jnp.where(
        small, 2.0 / jnp.maximum(w, 1e-6), 2.0 * jnp.arctan2(n, w) / jnp.where(small, 1.0, n)
    )
    return v * scale[..., None]


def _clip_norm(x: jax.Array, limit: float) -> jax.Array:
    n = jnp.linalg.norm(x, axis=-1, keepdims=True)
    return x * jnp.minimum(1.0, limit / jnp.maximum(n, 1e-12))


def pose_step(
    q: jax.Array,
    e: jax.Array,
    quat_err: jax.Array | None = None,
    wrap_last: bool = False,
    orient_first: bool = False,
    loose: bool = False,
) -> jax.Array:
    """One bounded damped-least-squares step of the nominal arm's joints toward the target
    an observation reports: q (..., 6) rad, e (..., 3) = p_tcp - p_target (m), quat_err
    (..., 4) = quat_tcp (x) conj(quat_target) or None (position only) -> dq (..., 6) rad.

    The TCP is asked to move by -e (at most MAX_POSITION_STEP) and to turn by the inverse
    of the error rotation, -rotation_vector(quat_err) in the world frame (at most
    MAX_ROTATION_STEP); dq = J^T (J J^T + DAMPING^2 I)^-1 dx with the position rows of J
    only when quat_err is None, then scaled down whole so that no joint moves more than
    MAX_STEP_JOINT. Near the target it is a Newton step (the error falls quadratically
    when repeated); far from it, a bounded move in the direction of the target. With the
    orientation and wrap_last, within WRAP_NEAR of the target, where the full Newton step
    would take the last joint past its limit and
    that joint spans a full turn, it moves the other way (toward the same angle less or
    plus 2 pi, at most MAX_STEP_JOINT per step; the TCP lies on that joint's axis, so the
    turn only rolls the tool and the other joints' step still holds the position and
    the tool axis): a local step would stop at the limit with the tool's roll off.
    With the orientation and `orient_first`, the tool is turned onto the target before
    the TCP closes in, as a peg is aligned before it is inserted: the rotation step is
    as above, and the TCP moves toward the target (at most MAX_POSITION_STEP) but no
    closer than ORIENT_FIRST_STANDOFF x the angle still left after this step's rotation,
    nor than ORIENT_FIRST_HOLD (1 cm) until the angle is below ORIENT_FIRST_ALIGNED (never
    away from it); then the whole pose converges together from 1 cm, so an evaluation
    that stops at the first step within a position tolerance finds the tool turned onto
    the target too (and pose_step_wrapping's flag, on within ORIENT_FIRST_NEAR, leaves
    that last approach to the IK step alone). With `loose` (training's rule,
    PolicyConfig.train_ik_orient_loose) there is neither: a stochastic policy keeps the tool
    about a degree off, and the hold would keep the sampled TCP off the target for good
    (benchmarks/NOTES.md section 27). With wrap_last as well, the flange's long way round
    is decided from the roll still to turn (the twist of the correction about the last
    joint's axis) at any distance, and the TCP's position is held while the last joint
    rolls (benchmarks/NOTES.md section 26). Known limit: where
    the last joint's goal lies within a step of its limit near +-pi, the choice between
    the short and the long way can flip from step to step as the other joints move (a
    cycle found by a review in a random-pose sweep; not on the fixed targets' poses). No
    gradient flows through it.
    """
    return pose_step_wrapping(q, e, quat_err, wrap_last, orient_first, loose=loose)[0]


def finish_step(q: jax.Array, e: jax.Array) -> jax.Array:
    """The IK finish of a position task (PolicyConfig.ik_finish): q (..., 6) rad, e (..., 3)
    = p_tcp - p_target (m) -> dq (..., 6) rad, the position-only IK step (`limited_step`)
    toward a point FINISH_HOLD (1 cm) short of the target until the TCP is within
    FINISH_WITHIN x FINISH_HOLD of it, then toward the target. The last step into an
    evaluation's 5 mm box is then a Newton step from about 1 cm, whose second-order error is
    a few hundredths of a millimetre; from 5 cm (one full MAX_POSITION_STEP) it is about
    3 mm (benchmarks/NOTES.md sections 27-28)."""
    dist = jnp.linalg.norm(e, axis=-1, keepdims=True)
    short = e * (1.0 - FINISH_HOLD / jnp.maximum(dist, 1e-12))
    aim = jnp.where(dist > FINISH_WITHIN * FINISH_HOLD, short, e)
    return limited_step(q, aim)


def limited_step(q: jax.Array, e: jax.Array) -> jax.Array:
    """pose_step (position only) that respects the joint limits: q (..., 6), e (..., 3) ->
    dq (..., 6). The joints that pose_step's step would take past a limit stop at it, and
    the others are solved again (damped least squares without those joints' columns) for
    the rest of the displacement, one active-set pass; then scaled down whole as pose_step
    (MAX_STEP_JOINT). Where no joint crosses a limit it is pose_step's step (to float32
    rounding). The env clips its joint targets to the limits, so a step that ignores them
    lands off its aim by what the clipped joints would have moved: on postures with a
    joint at its stop (the shoulder at -2.35 rad on some seeds' MARA approach) the finish
    entered the paper's 5 mm box up to 5 mm off, and with this step under 0.5 mm
    (benchmarks/NOTES.md section 52)."""
    chain = nominal_chain()
    lo6, hi6 = (np.asarray(x, np.float32) for x in joint_ranges())
    q, e = jax.lax.stop_gradient(q), jax.lax.stop_gradient(e)

    def one(q1: jax.Array, e1: jax.Array) -> jax.Array:
        jac = chain.jacobian(q1)[:3]
        dx = _clip_norm(-e1, MAX_POSITION_STEP)
        d1 = _joint_capped(dls_step(jac, dx))  # pose_step's step
        over = (q1 + d1 > hi6) | (q1 + d1 < lo6)
        pinned = jnp.where(over, jnp.clip(q1 + d1, lo6, hi6) - q1, 0.0)
        free = dls_step(jnp.where(over[None, :], 0.0, jac), dx - jac @ pinned)
        return _joint_capped(jnp.where(over, pinned, free))

    return jnp.vectorize(one, signature="(6),(3)->(6)")(q, e)


def _joint_capped(dq: jax.Array) -> jax.Array:
    """dq (6,) scaled down whole so that no joint moves more than MAX_STEP_JOINT."""
    big = jnp.max(jnp.abs(dq))
    return dq * jnp.minimum(1.0, MAX_STEP_JOINT / jnp.maximum(big, 1e-12))


def pose_step_wrapping(
    q: jax.Array,
    e: jax.Array,
    quat_err: jax.Array | None = None,
    wrap_last: bool = False,
    orient_first: bool = False,
    flag_roll: bool = False,
    loose: bool = False,
) -> tuple[jax.Array, jax.Array]:
    """pose_step's dq (..., 6) and a flag (..., bool) for where the IK step should act
    alone (PolicyConfig.ik_gate_wrap closes the residual's gate there): where it takes the
    last joint the long way round (only with quat_err and wrap_last); with orient_first
    and flag_roll, also while the flange still has more than MAX_ROTATION_STEP of roll
    to turn (the second half of a long way round looks like a short roll: the flag stays
    on through it; benchmarks/NOTES.md section 26); with orient_first's deployed rule
    (not `loose`), within ORIENT_FIRST_NEAR of the target position."""
    chain = nominal_chain()
    lo6, hi6 = last_joint_range()
    wrap = wrap_last and hi6 - lo6 >= 2 * jnp.pi - 0.01
    q, e = jax.lax.stop_gradient(q), jax.lax.stop_gradient(e)
    rot = None if quat_err is None else jax.lax.stop_gradient(quat_err)

    def one(q1: jax.Array, e1: jax.Array, *r: jax.Array) -> tuple[jax.Array, jax.Array]:
        jac = chain.jacobian(q1)
        dx = _clip_norm(-e1, MAX_POSITION_STEP)
        alone = jnp.zeros((), bool)
        if r and orient_first:  # turn the tool first: keep off by the angle left
            rot = -rotation_vector(r[0])
            turn = _clip_norm(rot, MAX_ROTATION_STEP)
            angle = jnp.linalg.norm(rot)
            dist = jnp.linalg.norm(e1)
            # training's rule: on the angle left after this step (first order)
            standoff = ORIENT_FIRST_STANDOFF * jnp.maximum(angle - MAX_ROTATION_STEP, 0.0)
            if not loose:  # and never closer than ORIENT_FIRST_HOLD until aligned
                floor = jnp.maximum(standoff, ORIENT_FIRST_HOLD)
                standoff = jnp.where(angle <= ORIENT_FIRST_ALIGNED, 0.0, floor)
                alone = dist < ORIENT_FIRST_NEAR
            move = jnp.clip(dist - standoff, 0.0, MAX_POSITION_STEP)
            dx = jnp.concatenate([-e1 * (move / jnp.maximum(dist, 1e-12)), turn])
        elif r:
            dx = jnp.concatenate([dx, _clip_norm(-rotation_vector(r[0]), MAX_ROTATION_STEP)])
        else:
            jac = jac[:3]
        dq = dls_step(jac, dx)
        use = rolling = jnp.zeros((), bool)
        if r and wrap:  # the last joint the long way round where the short way is blocked
            if orient_first:  # the flange's roll still to turn: the twist of the correction
                # conj(quat_err) about the last joint's axis (swing-twist), at any distance
                axis = jac[3:, 5] / jnp.maximum(jnp.linalg.norm(jac[3:, 5]), 1e-12)
                quat = quat_canonical(r[0])
                goal = q1[5] + 2.0 * jnp.arctan2(-jnp.sum(quat[1:] * axis), quat[0])
                near = jnp.ones((), bool)  # the roll still to turn, wherever the TCP is
            else:
                full = dls_step(jac, jnp.concatenate([-e1, -rotation_vector(r[0])]))
                goal = q1[5] + full[5]
                near = jnp.linalg.norm(e1) < WRAP_NEAR  # far away the Newton step means little
            shift = jnp.where(goal > hi6, -2 * jnp.pi, jnp.where(goal < lo6, 2 * jnp.pi, 0.0))
            other = goal + shift
            use = near & (shift != 0.0) & (other >= lo6) & (other <= hi6)
            if orient_first and flag_roll:  # past half a turn, the rest of the long way is
                # the short way: a roll of the flange is the step's own until it fits in one
                rolling = jnp.abs(goal - q1[5]) > MAX_ROTATION_STEP
            long_way = jnp.clip(other - q1[5], -MAX_STEP_JOINT, MAX_STEP_JOINT)
            if orient_first:  # hold the position while the flange rolls the long way:
                # joints 1-5 keep the TCP where it is and turn the tool axis (the rotation
                # less its part about the flange's axis), the last joint rolls
                turn = dx[3:] - jnp.sum(dx[3:] * axis) * axis
                rhs = jnp.concatenate([-jac[:3, 5] * long_way, turn])
                held = jnp.append(dls_step(jac[:, :5], rhs), long_way)
                dq = jnp.where(use, held, dq)
            dq = dq.at[5].set(jnp.where(use, long_way, dq[5]))
        return _joint_capped(dq), use | rolling | alone

    if rot is None:
        return jnp.vectorize(one, signature="(6),(3)->(6),()")(q, e)
    return jnp.vectorize(one, signature="(6),(3),(4)->(6),()")(q, e, rot)


def wrist_flip(q: jax.Array) -> jax.Array:
    """(..., 6) rad -> the other wrist branch of the same tool pose: joints 4 and 6 half a
    turn round (the way that stays within their +-pi ranges) and joint 5 mirrored. On the
    nominal chain the tool's orientation is the same to rounding and the TCP 1.6 mm away
    (the wrist's three axes miss one point by that much), so IK steps from it converge on
    that branch."""
    half = jnp.float32(np.pi)
    turn = lambda x: x - half * jnp.where(x < 0.0, -1.0, 1.0)  # noqa: E731
    return jnp.stack([q[..., 0], q[..., 1], q[..., 2], turn(q[..., 3]), -q[..., 4],
                      turn(q[..., 5])], axis=-1)  # fmt: skip


def ik_landing(q: jax.Array, target_pos: jax.Array, target_quat, steps: int) -> jax.Array:
    """(G, 6) rad -> (G, 6): `steps` IK steps (`pose_step`, with the long way round for
    the last joint where the orientation is asked) on the nominal arm from q (clipped to
    the joint ranges, as every step, as the env clips its targets) toward the target:
    position (G, 3) m and, unless None, quaternion (G, 4)."""
    tcp = jnp.vectorize(nominal_chain().tcp, signature="(6)->(3),(4)")
    lo, hi = (jnp.asarray(x, jnp.float32) for x in joint_ranges())

    def step(q, _):
        pos, quat = tcp(q)
        err = None if target_quat is None else quat_mul(quat, quat_conj(target_quat))
        dq = pose_step(q, pos - target_pos, err, wrap_last=err is not None)
        return jnp.clip(q + dq, lo, hi), None

    return jax.lax.scan(step, jnp.clip(q, lo, hi), None, length=steps)[0]
