"""One physics step of the arm in plain jnp: `mjx.step` of the contact-free chain.

The real driver with contacts detected (`real_contacts='detect'`) integrates the six-hinge
chain with no contact forces. MJX's generic step (every body, geom, site and camera;
a constraint solver with a while loop over whatever rows the model has) does far more
than that needs; this module is what it needs, written out for the chain, the model's
servos and its joint-limit and friction-loss rows (issue 14), in fixed, fusable array
code (no while loop, no scatter, no library call per 6 x 6 matrix). MJX stays the
reference: tests/test_dynamics.py checks `step` against `mjx.step` of the same
`mjx.Model`. One difference is by design: MJX's constraint solver stops after the
model's `iterations` (4, assets/mara.xml) and its line search after `ls_iterations`,
converged or not; this step solves the same convex problem to its minimum, so where
MJX has not converged (several joints past their limits at once, at speed, or dry
friction) it is the closer of the two (checked against MJX with 100 iterations).

Per step, as MuJoCo's `mj_step` with the implicitfast integrator (the model's):

* kinematics: `mara_mjx.envs.chain`; each body's centre of mass c_b and world inertia
  I_b; the Jacobians of c_b, Jv_b (3, 6) and Jw_b (3, 6), column j <= b: axis_j x
  (c_b - anchor_j) and axis_j (a serial chain: body b moves with joints 1..b);
* mass matrix M = sum_b m_b Jv_b' Jv_b + Jw_b' I_b Jw_b + diag(armature) (the
  composite-rigid-body sum, as MuJoCo's `mj_crb` computes it in spatial algebra);
* bias forces (recursive Newton-Euler with qacc = 0 and gravity, MuJoCo's qfrc_bias):
  sum_b Jv_b' m_b (a_b - g) + Jw_b' (I_b wdot_b + w_b x I_b w_b), with a_b, wdot_b the
  velocity-product accelerations d/dt(J_b) qdot;
* servos: each actuator's force gain ctrl + b0 + b1 q + b2 qdot (ctrl clamped to its
  range), gravity compensation added where the joint routes it through its actuators,
  the total clamped to the joint's effort limits; passive damping -damping qdot;
* constraints: MuJoCo's joint-limit rows (active beyond the range) and dof friction-loss
  rows (a model built with friction: the randomised real driver), with MJX's impedance
  and reference acceleration; the constrained acceleration minimises MuJoCo's convex
  cost (Gauss + constraint costs) by Newton's method with an exact line search (the
  cost is piecewise quadratic along a line), a fixed number of iterations, no while
  loop;
* implicitfast: qacc = (M - dt dforce/dqdot)^-1 (smooth + constraint forces), then
  qvel += dt qacc, qpos += dt qvel.

Everything traced comes from the `mjx.Model` passed in (masses, inertias, damping,
armature, friction loss, servo gains: a randomised env's per-env model works as is);
the structure (chain, ids, which terms exist) is read once from the C model, which
`Dynamics.from_model` checks is of the form written out here.

    dyn = Dynamics.from_model(mj_model)
    q, qvel = dyn.step(mjx_model, q, qvel, ctrl)    # as mjx.step's qpos, qvel
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mara_mjx.envs.chain import Chain
from mara_mjx.envs.geometry import quat_to_mat_np
from mara_mjx.envs.linalg import spd_solve

# Newton iterations of the constraint solve, a fixed count (no while loop). Newton's method
# with exact line searches on a piecewise quadratic ends once the rows' zones are right.
# Measured on random states and on trajectories pressed against the limits: joint-limit
# rows alone settle within 2 iterations; with the randomised model's dry-friction rows,
# within 8 (tests/test_dynamics.py checks both).
LIMIT_ITERATIONS = 4
FRICTION_ITERATIONS = 8
_MINVAL, _MINIMP, _MAXIMP = mujoco.mjMINVAL, mujoco.mjMINIMP, mujoco.mjMAXIMP


@dataclasses.dataclass(frozen=True)
class Dynamics:
    """The chain's constants and the model's structure (numpy, resolved once). Joint,
    dof and qpos index i all belong to the chain's body i (checked)."""

    chain: Chain
    body_ids: np.ndarray  # (6,) MuJoCo ids of the moving bodies, base to flange
    ipos: np.ndarray  # (6, 3) centre of mass in the body frame
    irot: np.ndarray  # (6, 3, 3) principal inertia axes in the body frame
    act_joint: np.ndarray  # (nu,) each actuator's joint
    act_gear: np.ndarray  # (nu,)
    ctrl_limited: np.ndarray  # (nu,) bool
    force_limited: np.ndarray  # (nu,) bool
    actfrc_limited: np.ndarray  # (6,) bool
    act_gravcomp: np.ndarray  # (6,) 0/1: gravity compensation through the actuators
    limited: np.ndarray  # (6,) bool: joint-limit rows
    friction: np.ndarray  # (6,) bool: friction-loss rows (MJX: dof_frictionloss > 0)

    @classmethod
    def from_model(cls, m: mujoco.MjModel) -> Dynamics:
        """The dynamics of `m`; ValueError unless `m` is what this module writes out: the
        six-hinge chain as its only joints, in order; joint-transmission actuators with no
        activation dynamics, fixed gain and affine (or no) bias; no springs, joint
        margins, tendons, equality constraints, flexes or fluid forces; Newton's solver
        and the implicitfast integrator; contacts at most (which this step leaves out)
        disabled."""
        chain = Chain.from_model(m)
        body_ids = np.array(chain.body_ids)
        in_order = np.arange(6)
        ok = m.njnt == 6 and m.nv == 6 and m.nq == 6
        ok = ok and np.array_equal([m.body_jntadr[b] for b in body_ids], in_order)
        ok = ok and np.array_equal(m.jnt_dofadr, in_order)
        ok = ok and np.array_equal(m.jnt_qposadr, in_order)
        ok = ok and m.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        ok = ok and m.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON
        ok = ok and (m.opt.disableflags & ~int(mujoco.mjtDisableBit.mjDSBL_CONTACT)) == 0
        ok = ok and m.opt.enableflags == 0 and m.opt.density == 0 and m.opt.viscosity == 0
        ok = ok and m.neq == 0 and m.ntendon == 0 and m.na == 0 and m.nflex == 0
        ok = ok and not np.any(m.jnt_stiffness) and not np.any(m.jnt_margin)
        ok = ok and np.all(m.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT)
        ok = ok and np.all(m.actuator_dyntype == mujoco.mjtDyn.mjDYN_NONE)
        ok = ok and np.all(m.actuator_gaintype == mujoco.mjtGain.mjGAIN_FIXED)
        biases = (mujoco.mjtBias.mjBIAS_NONE, mujoco.mjtBias.mjBIAS_AFFINE)
        ok = ok and np.all(np.isin(m.actuator_biastype, biases))
        if not ok:
            raise ValueError("the model is not a six-hinge chain of the form Dynamics writes out")
        return cls(
            chain=chain,
            body_ids=body_ids,
            ipos=m.body_ipos[body_ids].copy(),
            irot=np.stack([quat_to_mat_np(m.body_iquat[b]) for b in body_ids]),
            act_joint=m.actuator_trnid[:, 0].copy(),
            act_gear=m.actuator_gear[:, 0].copy(),
            ctrl_limited=m.actuator_ctrllimited.astype(bool),
            force_limited=m.actuator_forcelimited.astype(bool),
            actfrc_limited=m.jnt_actfrclimited.astype(bool),
            act_gravcomp=m.jnt_actgravcomp.astype(np.float64),
            limited=m.jnt_limited.astype(bool),
            friction=m.dof_frictionloss > 0,
        )

    # ------------------------------------------------------------------ the step
    def step(self, model, q: jax.Array, qvel: jax.Array, ctrl: jax.Array):
        """One physics step of `model` (an `mjx.Model` of the C model this was built from,
        possibly with per-env physics): q (6,) rad, qvel (6,) rad/s, ctrl (nu,) ->
        (q', qvel'), as `mjx.step`'s qpos and qvel."""
        dt = model.opt.timestep
        with jax.named_scope("chain_smooth"):
            mass, qfrc_smooth, kv = self._smooth(model, q, qvel, ctrl)
        with jax.named_scope("chain_constraint"):
            qacc_smooth = spd_solve(mass, qfrc_smooth)
            qfrc_constraint = self._constraint(model, q, qvel, mass, qacc_smooth)
        with jax.named_scope("chain_integrate"):
            # implicitfast: the servos' and dampers' velocity derivative, implicit
            qacc = spd_solve(mass + dt * jnp.diag(kv), qfrc_smooth + qfrc_constraint)
            qvel = qvel + dt * qacc
            return q + dt * qvel, qvel

    def _smooth(self, model, q, qvel, ctrl):
        """Mass matrix (6, 6), smooth force (6,) (N m) and -d force / d qdot (6,)."""
        f32 = jnp.float32
        xs, rots, axes, anchors = self.chain.body_frames(q)
        ids = self.body_ids
        mass, gravity = model.body_mass[ids], model.opt.gravity
        com = xs + jnp.einsum("bij,bj->bi", rots, jnp.asarray(self.ipos, f32))
        frame = rots @ jnp.asarray(self.irot, f32)
        inertia = jnp.einsum("bij,bj,bkj->bik", frame, model.body_inertia[ids], frame)
        # Jacobians of the centres of mass, (body b, joint j, xyz): zero for j > b
        below = jnp.asarray(np.tril(np.ones((6, 6))), f32)
        jw = axes[None] * below[..., None]
        jv = jnp.cross(jw, com[:, None, :] - anchors[None])
        m_mat = jnp.einsum("b,bjx,bkx->jk", mass, jv, jv)
        m_mat = m_mat + jnp.einsum("bjx,bxy,bky->jk", jw, inertia, jw)
        m_mat = m_mat + jnp.diag(model.dof_armature)

        # velocity-product accelerations (qacc = 0): d/dt axis_j = w_j x axis_j; the
        # anchor of joint j moves with the joints i < j
        w = jnp.einsum("bjx,j->bx", jw, qvel)  # (6, 3) body angular velocities
        v = jnp.einsum("bjx,j->bx", jv, qvel)  # (6, 3) centre-of-mass velocities
        axis_dot = jnp.cross(w, axes)
        lever = jnp.cross(axes[None], anchors[:, None] - anchors[None])  # (anchor j, joint i)
        v_anchor = jnp.einsum("jix,ji,i->jx", lever, below - jnp.eye(6), qvel)
        acc = jnp.cross(axis_dot[None], com[:, None] - anchors[None])
        acc = acc + jnp.cross(axes[None], v[:, None] - v_anchor[None])
        acc = jnp.einsum("bjx,bj,j->bx", acc, below, qvel)
        wdot = jnp.einsum("bj,jx,j->bx", below, axis_dot, qvel)
        force = mass[:, None] * (acc - gravity)
        spin = jnp.einsum("bij,bj->bi", inertia, w)
        torque = jnp.einsum("bij,bj->bi", inertia, wdot) + jnp.cross(w, spin)
        bias = jnp.einsum("bjx,bx->j", jv, force) + jnp.einsum("bjx,bx->j", jw, torque)
        lift = -gravity * (mass * model.body_gravcomp[ids])[:, None]
        gravcomp = jnp.einsum("bjx,bx->j", jv, lift)

        # servos: force = gain ctrl + b0 + b1 length + b2 velocity, per actuator
        gear, joint = jnp.asarray(self.act_gear, f32), self.act_joint
        lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
        ctrl = jnp.where(self.ctrl_limited, jnp.clip(ctrl, lo, hi), ctrl)
        bias_prm = model.actuator_biasprm
        act = model.actuator_gainprm[:, 0] * ctrl + bias_prm[:, 0]
        act = act + bias_prm[:, 1] * gear * q[joint] + bias_prm[:, 2] * gear * qvel[joint]
        lo, hi = model.actuator_forcerange[:, 0], model.actuator_forcerange[:, 1]
        act = jnp.where(self.force_limited, jnp.clip(act, lo, hi), act)
        to_joint = jnp.asarray(np.eye(6)[joint].T, f32) * gear  # (6, nu): the moments
        through = jnp.asarray(self.act_gravcomp, f32)
        actuator = to_joint @ act + gravcomp * through
        lo, hi = model.jnt_actfrcrange[:, 0], model.jnt_actfrcrange[:, 1]
        actuator = jnp.where(self.actfrc_limited, jnp.clip(actuator, lo, hi), actuator)
        passive = -model.dof_damping * qvel + gravcomp * (1 - through)
        kv = model.dof_damping - (to_joint * gear) @ bias_prm[:, 2]
        return m_mat, passive - bias + actuator, kv

    def _constraint(self, model, q, qvel, mass, qacc_smooth):
        """MuJoCo's constraint force (6,) (N m) of the joint-limit and friction-loss rows,
        as MJX builds them (`constraint._efc_limit_slide_hinge`, `_efc_friction`): one row
        per joint and kind, J = sign e_dof (sign 0: no row, or a limit not reached)."""
        groups = []  # (sign, impedance position, reference position, solref, solimp, floss)
        if self.limited.any():
            dist_lo, dist_hi = q - model.jnt_range[:, 0], model.jnt_range[:, 1] - q
            pos = jnp.minimum(dist_lo, dist_hi)
            active = (pos < 0) & self.limited
            sign = jnp.where(dist_lo < dist_hi, 1.0, -1.0) * active
            groups.append((sign, pos, pos * active, model.jnt_solref, model.jnt_solimp, None))
        if self.friction.any():
            on, zero = jnp.asarray(self.friction, jnp.float32), jnp.zeros(6)
            groups.append((on, zero, zero, model.dof_solref, model.dof_solimp,
                           model.dof_frictionloss * on))  # fmt: skip
        if not groups:
            return jnp.zeros(6)
        invweight = model.dof_invweight0
        rows = []
        for sign, pos_imp, pos_aref, solref, solimp, floss in groups:
            k, b, imp = _kbi(solref, solimp, pos_imp, model.opt.timestep)
            dcoef = 1.0 / jnp.maximum(invweight * (1 - imp) / imp, _MINVAL)
            aref = -b * (sign * qvel) - k * imp * pos_aref
            rows.append((sign, dcoef, aref, jnp.zeros(6) if floss is None else floss))
        sign, dcoef, aref, floss = (jnp.stack(x) for x in zip(*rows, strict=True))
        friction = np.array([g[-1] is not None for g in groups])[:, None]  # (groups, 1)
        iterations = FRICTION_ITERATIONS if friction.any() else LIMIT_ITERATIONS
        return _solve(mass, qacc_smooth, sign, dcoef, aref, floss, friction, iterations)


def _kbi(solref, solimp, pos, timestep):
    """Stiffness, damping and impedance of constraint rows (MJX's `constraint._kbi`)."""
    timeconst, dampratio = solref[..., 0], solref[..., 1]
    timeconst = jnp.maximum(timeconst, 2 * timestep)  # refsafe
    dmin = jnp.clip(solimp[..., 0], _MINIMP, _MAXIMP)
    dmax = jnp.clip(solimp[..., 1], _MINIMP, _MAXIMP)
    width = jnp.maximum(_MINVAL, solimp[..., 2])
    mid = jnp.clip(solimp[..., 3], _MINIMP, _MAXIMP)
    power = jnp.maximum(1, solimp[..., 4])
    k = 1 / (dmax * dmax * timeconst * timeconst * dampratio * dampratio)
    b = 2 / (dmax * timeconst)
    k = jnp.where(solref[..., 0] <= 0, -solref[..., 0] / (dmax * dmax), k)
    b = jnp.where(solref[..., 1] <= 0, -solref[..., 1] / dmax, b)
    x = jnp.abs(pos) / width
    imp_a = (1.0 / jnp.power(mid, power - 1)) * jnp.power(x, power)
    imp_b = 1 - (1.0 / jnp.power(1 - mid, power - 1)) * jnp.power(1 - x, power)
    imp = dmin + jnp.where(x < mid, imp_a, imp_b) * (dmax - dmin)
    imp = jnp.where(x > 1.0, dmax, jnp.clip(imp, dmin, dmax))
    return k, b, imp


def _solve(mass, qacc_smooth, sign, dcoef, aref, floss, friction, iterations):
    """The constraint force (6,) at the minimum over qacc of MuJoCo's primal cost

        1/2 (a - a0)' M (a - a0) + sum_rows s(x),   x = J a - aref,

    rows in groups of one per dof ((groups, 6) arrays; J = sign e_dof). Limit rows:
    s = D x^2 / 2 for x < 0, else 0. Friction rows (`friction`): D x^2 / 2 for
    |x| < R f, linear (f |x| - R f^2 / 2) beyond, R = 1 / D; quadratic everywhere when
    f = 0, as MJX. The cost is convex and C1: Newton's method from a0 = qacc_smooth
    with exact line searches, `iterations` times (no while loop). A step is taken
    only where it lowers the cost: at the minimum the Newton direction is rounding
    noise, and so is the line search along it."""
    rf = floss / dcoef
    linear = friction & (floss > 0)

    def row_terms(x):
        """Force -ds/dx, curvature d2s/dx2 and cost s of every row at residuals x
        (..., groups, 6)."""
        neg, pos = linear & (x <= -rf), linear & (x >= rf)
        quad = jnp.where(friction, ~neg & ~pos, x < 0)
        force = jnp.where(quad, -dcoef * x, jnp.where(neg, floss, jnp.where(pos, -floss, 0.0)))
        cost = jnp.where(quad, 0.5 * dcoef * x * x, 0.0)
        cost = cost + jnp.where(neg | pos, floss * (jnp.abs(x) - 0.5 * rf), 0.0)
        return force, jnp.where(quad, dcoef, 0.0), cost

    a = qacc_smooth
    for _ in range(iterations):
        x = sign * a - aref
        force, curv, _ = row_terms(x)
        grad = mass @ (a - qacc_smooth) - jnp.sum(sign * force, axis=0)
        s = -spd_solve(mass + jnp.diag(jnp.sum(curv * sign * sign, axis=0)), grad)
        v = sign * s
        mass_s = mass @ s
        gauss0, gauss1 = (a - qacc_smooth) @ mass_s, s @ mass_s

        def slope(alpha, x=x, v=v, gauss0=gauss0, gauss1=gauss1):
            """d/dalpha of the cost at a + alpha s, alpha (k,)."""
            f = row_terms(x + alpha[:, None, None] * v)[0]
            return gauss0 + alpha * gauss1 - jnp.sum(f * v, axis=(1, 2))

        alpha = _line_minimum(slope, x, v, rf, friction)
        rows = row_terms(x + alpha * v)[2] - row_terms(x)[2]
        change = alpha * gauss0 + 0.5 * alpha * alpha * gauss1 + jnp.sum(rows)
        a = jnp.where(change < 0.0, a + alpha * s, a)
    force = row_terms(sign * a - aref)[0]
    return jnp.sum(sign * force, axis=0)


def _line_minimum(slope, x, v, rf, friction):
    """The exact minimiser alpha >= 0 of the cost along a line: its slope is continuous,
    nondecreasing and piecewise linear in alpha, with knots where a row's residual
    x + alpha v crosses 0 (limit rows) or +-R f (friction rows). As in
    `lean.segment_box_distance`: the largest knot with slope <= 0 and the smallest with
    slope >= 0 bound one linear piece, where the slope is interpolated to 0; past every
    knot (one piece) two points extrapolate it when it is still < 0 there."""
    safe = jnp.where(jnp.abs(v) > 1e-20, v, 1e-20)  # a row the line hardly moves
    bounds = [(-x / safe)[~friction[:, 0]], ((rf - x) / safe)[friction[:, 0]],
              ((-rf - x) / safe)[friction[:, 0]]]  # fmt: skip
    knots = jnp.clip(jnp.concatenate([b.ravel() for b in bounds]), 0.0, 1e20)
    far = 2.0 * jnp.max(knots) + 1.0
    alphas = jnp.concatenate([jnp.zeros(1), knots, jnp.stack([far, 2.0 * far])])
    g = slope(alphas)
    down, up = g <= 0.0, g >= 0.0
    lo, hi = jnp.max(jnp.where(down, alphas, 0.0)), jnp.min(jnp.where(up, alphas, 2.0 * far))
    g_lo = jnp.max(jnp.where(down, g, -jnp.inf))
    g_hi = jnp.min(jnp.where(up, g, jnp.inf))
    crossing = (hi > lo) & (g_hi > g_lo)
    alpha = lo - g_lo * (hi - lo) / jnp.where(crossing, g_hi - g_lo, 1.0)
    alpha = jnp.clip(jnp.where(crossing, alpha, lo), lo, hi)
    rise = jnp.maximum(g[-1] - g[-2], 1e-30)
    return jnp.where(g[-1] < 0.0, 2.0 * far - g[-1] * far / rise, alpha)
