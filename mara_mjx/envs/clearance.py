"""The deployed collision guard: no commanded posture closer to a contact than a margin.

A deployed policy's joint targets q + dq are checked before they are sent: where the
nominal arm at q + dq (clipped to the joint limits, as the env clips its targets) would
come closer than `margin` to any listed contact pair (the arm's links, the gripper, the
base and the table: the pairs the env's collision check reads, as signed distances of
the lean pass, envs/lean.py), the step is shortened to alpha dq, alpha found by bisection
along the step, so that the arm stops short of the contact and the policy chooses again
from there (PolicyConfig.collision_guard_mm; benchmarks/NOTES.md section 38). Where no
fraction of the step keeps the clearance, it loses its part toward the contact and the arm
slides along the margin instead (a deterministic policy asks the same step again at the
same posture, so a stop there was for good: section 52).

    dq = keep_clear(q, dq, margin)          # (..., 6), (..., 6) -> (..., 6) rad

The margin asked for is never more than the clearance the arm already has at q, so a
posture that is already within the margin (a target near the table, sensor noise) may
still move, as long as it does not move closer. The check is of the posture each step
lands in, not of the path between: on the train driver that is exactly the env's
collision check; on a servo-driven arm the steps are small (EvalConfig.rate_limit) and
the margin covers the path between two checks. The nominal arm is the drawing's: a
randomised arm differs from it by its joint zero offsets (milliradians), which the
margin also covers.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.envs.lean import LeanArm

KEEP_CLEAR_ITERS = 8
"""Bisection halvings of keep_clear (the step is kept to 1/256 of its length)."""


@functools.lru_cache(maxsize=1)
def nominal_lean() -> LeanArm:
    """The lean collision pass of the MARA model in the package's assets (built once)."""
    from mara_mjx.envs.arm import load_model  # arm imports lean: no cycle at import time

    return LeanArm.from_model(load_model())


def clearance(q: jax.Array) -> jax.Array:
    """q (..., 6) -> (...,) the smallest signed distance (m) of the listed contact pairs of
    the nominal arm at q (negative: penetrating, which the env counts as a collision)."""
    lean = nominal_lean()

    def one(q1):
        cc, cb = lean.distances(q1)
        return jnp.minimum(jnp.min(cc), jnp.min(cb))

    return jnp.vectorize(one, signature="(6)->()")(q)


def keep_clear(
    q: jax.Array, dq: jax.Array, margin: float, iters: int = KEEP_CLEAR_ITERS
) -> jax.Array:
    """dq (..., 6), shortened to alpha dq where the nominal arm at q + dq (clipped to the
    joint limits) would come closer than min(margin, clearance(q)) to a contact (m); alpha
    by `iters` halvings, the largest fraction found that keeps the clearance. Elsewhere
    dq unchanged. Where the step is blocked from its start (even its 2^-iters part comes
    closer: then the bisection, along a clearance that falls monotonically, keeps
    nothing), the step slides instead: dq without its part toward the contact along the
    clearance's gradient (finite differences) and with a little away from it (SLIDE_OUT),
    no larger on any joint than dq, shortened the same way, so that the arm moves along
    the margin rather than stopping for good in front of it (a deterministic policy
    re-asked at the same posture would ask the same step: benchmarks/NOTES.md section 52).
    Wherever the 2^-iters part keeps the clearance, the output is the plain guard's.
    Batch-first with the loop outermost and its values in the carry, as
    task_space.stop_outside, so that jax2onnx exports it."""
    from mara_mjx.envs.task_space import joint_ranges

    lo6, hi6 = (np.asarray(x, np.float32) for x in joint_ranges())
    step = dq  # the gradient flows through the step itself, not through alpha
    q, dq = jax.lax.stop_gradient(q), jax.lax.stop_gradient(dq)

    def landing(alpha, q, dq):  # alpha (...,) -> (..., 6) the posture alpha dq lands in
        return jnp.clip(q + alpha[..., None] * dq, lo6, hi6)

    def clear(alpha, q, dq, need):  # alpha (...,) -> (...,) bool
        return clearance(landing(alpha, q, dq)) >= need

    ones = jnp.ones(q.shape[:-1], q.dtype)
    # The nine clearances that need none of the others (at q, after the whole step, after
    # its 2^-iters part, at the gradient's six nudges) in one lax.map: one copy of the
    # kinematics and pair distances in the program instead of nine (40-50% off the CPU
    # compile of the programs that hold the guard), each evaluated at the batch's own
    # shape, so bitwise as nine calls. (One call on the stacked (9, ...) batch is not:
    # XLA's CPU code for another shape rounds differently, and bisections then decide
    # otherwise.)
    eye = np.eye(6, dtype=np.float32) * SLIDE_H
    postures = [q, landing(ones, q, dq), landing(ones * 0.5**iters, q, dq)]
    postures += [q + eye[i] for i in range(6)]
    here, whole, least, *nudged = jax.lax.map(clearance, jnp.stack(postures))
    need = jnp.minimum(jnp.float32(margin), here)
    blocked = ~(whole >= need)
    # blocked from its start (even 2^-iters of the step comes closer): there the step
    # slides. It loses its part along the clearance's gradient g (forward differences:
    # plain ops that jax2onnx traces) and gains SLIDE_OUT of its size along g, so that the
    # slid step gains clearance to first order and the checks below are not decided by
    # rounding (a step exactly along the margin's level set is: JAX and the ONNX graph
    # then disagree); scaled back to dq's largest joint move; that is what the bisection
    # shortens.
    stuck = blocked & ~(least >= need)
    grad = jnp.stack([(c - here) / SLIDE_H for c in nudged], -1)
    g2 = jnp.maximum(jnp.sum(grad * grad, -1, keepdims=True), 1e-12)
    toward = jnp.minimum(jnp.sum(grad * dq, -1, keepdims=True), 0.0)
    size = jnp.linalg.norm(dq, axis=-1, keepdims=True)
    slid = dq + (SLIDE_OUT * size * jnp.sqrt(g2) - toward) * grad / g2
    biggest = jnp.max(jnp.abs(dq), -1, keepdims=True)
    slid = slid * jnp.minimum(
        1.0, biggest / jnp.maximum(jnp.max(jnp.abs(slid), -1, keepdims=True), 1e-12)
    )
    slide = jnp.where(stuck[..., None], slid - dq, 0.0)
    dq = dq + slide
    blocked = ~clear(ones, q, dq, need)  # (unchanged where the slide is an exact 0)

    def halve(_, carry):
        lo, hi, q, dq, need = carry
        mid = 0.5 * (lo + hi)
        ok = clear(mid, q, dq, need)
        return jnp.where(ok, mid, lo), jnp.where(ok, hi, mid), q, dq, need

    lo = jax.lax.fori_loop(0, iters, halve, (jnp.zeros_like(ones), ones, q, dq, need))[0]
    alpha = jnp.where(blocked, lo, 1.0)
    # (the gradient flows through `step` as alpha I; the slide is a constant to it: the
    # guard is deployed only)
    return alpha[..., None] * (step + slide)


SLIDE_H = 1e-2
"""keep_clear: rad, the finite-difference step of the clearance's gradient."""
SLIDE_OUT = 0.05
"""keep_clear: a slid step's part away from the contact, as a fraction of its size."""
