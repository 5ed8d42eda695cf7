"""The lean pose pass (mara_mjx/envs/lean.py) as one elementwise, structure-of-arrays
program: EnvConfig(kinematics="fused"), an env step that moves fewer bytes (issue 35).

`jax.vmap(LeanArm.pose)` over a batch is correct but, on a GPU, expensive in memory
traffic: every (P, 3) / (3, 3) intermediate is an array of the batch written between XLA
kernels and the chain's 3x3 products become separate batched GEMMs (about 95 kernels and
17 kB per env per train-driver step on an H100). This module writes the same maths (the
chain's body frames, the TCP, Shepperd's quaternion, the 24 pairs' signed distances)
with scalars only:

* a value is either a Python float (a model constant, folded at trace time) or a (B,)
  array of the batch; a 3-vector is a tuple of 3 values and a 3x3 matrix a tuple of 3
  rows. Products with the model's constant matrices and vectors are written out term by
  term, with constant-constant products done in Python (float64) and exact zeros and
  ones dropped (the base and box rotations are identities, the hinge axes are unit
  vectors along x or z), so the trace holds only the work that depends on q;
* every op is elementwise (add, mul, div, min, max, where, abs, sqrt, sin, cos,
  compares): no stack, concatenate, dot, gather or reduction over an axis. The
  reference's reductions over the 8 knots of a capsule-box test become running min/max,
  `any` over the pairs a chain of `|`, and Shepperd's argmax nested `where`s with
  jnp.argmax's tie-break (the first maximum wins).

So XLA sees one elementwise graph, q in and pose out (how many loop fusions it cuts that
into is XLA's choice: on the CPU 8, each recomputing the shared chain), and the same Python
function is the body of a Pallas kernel (`fused_pose(..., backend="pallas")`), which loads
each joint column as a (block,) vector, runs `soa_pose` on it and stores 3 + 4 + 1
columns. Results equal LeanArm.pose's within float32 rounding (tests/test_fused_pose.py);
the collided bit can differ only where a pair's signed distance is within rounding of 0.
Two rewrites of the same maths: the squared lengths of the capsules' segments are folded
to their constants (a rotation keeps lengths), where the reference computes them from the
rotated segment, and the capsule-box slope's max(|p| - h, 0) sign(p) is a select (bit for
bit the same, without abs and sign).

On an H100 the pose pass alone runs at 1.6-1.8 G poses/s fused by XLA against the
lean pass's 136 M, and compiles 10-15 s longer (benchmarks/results/fused_pose/).

    env = mara_mjx.make("MARACollisionOrient", kinematics="fused")   # arm_pose in the step
    lean = LeanArm.from_model(env.arm.mj_model)
    tcp, quat, hit = soa_pose(lean, tuple(q[:, i] for i in range(6)))  # q (B, 6)
    tcp, quat, hit = fused_pose(lean, q)                     # (B, 3), (B, 4), (B,) bool
    tcp, quat, hit = fused_pose(lean, q, backend="pallas")   # a Pallas (Triton) kernel
    fused_pose(lean, q, backend="pallas", interpret=True)    # the same, run on the CPU
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.envs.lean import LeanArm
from mara_mjx.envs.pose import ArmPose

INF = math.inf


# ------------------------------------------------ scalars: a Python float or a (B,) array
def _is_const(v) -> bool:
    return isinstance(v, float)


def _add(a, b):
    if _is_const(a) and a == 0.0:
        return b
    if _is_const(b) and b == 0.0:
        return a
    return a + b


def _sub(a, b):
    if _is_const(b) and b == 0.0:
        return a
    if _is_const(a) and a == 0.0:
        return -b
    return a - b


def _mul(a, b):
    if _is_const(b):
        a, b = b, a
    if _is_const(a) and not _is_const(b):
        if a == 0.0:
            return 0.0
        if a == 1.0:
            return b
        if a == -1.0:
            return -b
    return a * b


def _sum(*terms):
    return functools.reduce(_add, terms, 0.0)


def _elementwise(jnp_fn, py_fn):
    """`jnp_fn` on arrays, `py_fn` when every argument is a constant (no jnp constant
    enters the trace: a Pallas kernel may not capture arrays)."""

    def fn(*args):
        if all(_is_const(a) for a in args):
            return float(py_fn(*args))
        return jnp_fn(*args)

    return fn


_max = _elementwise(jnp.maximum, max)
_min = _elementwise(jnp.minimum, min)
_abs = _elementwise(jnp.abs, abs)
_sqrt = _elementwise(jnp.sqrt, math.sqrt)


def _clip(x, lo, hi):
    return _min(_max(x, lo), hi)


def _where(cond, a, b):
    if isinstance(cond, bool | np.bool_):
        return a if cond else b
    if _is_const(a) and _is_const(b) and a == b:
        return a
    return jnp.where(cond, a, b)


def _vec(v) -> tuple:
    return tuple(float(x) for x in np.asarray(v, np.float64))


def _mat(m) -> tuple:
    return tuple(_vec(row) for row in np.asarray(m, np.float64))


def _dot(u, v):
    return _sum(*(_mul(a, b) for a, b in zip(u, v, strict=True)))


def _mv(m, v) -> tuple:
    return tuple(_dot(row, v) for row in m)


def _mm(a, b) -> tuple:
    cols = tuple(zip(*b, strict=True))
    return tuple(tuple(_dot(row, col) for col in cols) for row in a)


def _vadd(u, v) -> tuple:
    return tuple(_add(a, b) for a, b in zip(u, v, strict=True))


def _vsub(u, v) -> tuple:
    return tuple(_sub(a, b) for a, b in zip(u, v, strict=True))


def _vscale(u, s) -> tuple:
    return tuple(_mul(a, s) for a in u)


def _cross(u, v) -> tuple:
    return (
        _sub(_mul(u[1], v[2]), _mul(u[2], v[1])),
        _sub(_mul(u[2], v[0]), _mul(u[0], v[2])),
        _sub(_mul(u[0], v[1]), _mul(u[1], v[0])),
    )


# ------------------------------------------------------------------------ kinematics
def _rodrigues(axis: tuple, c, s) -> tuple:
    """chain._rodrigues with a constant unit axis and c, s = cos, sin of the angle."""
    x, y, z = axis
    t = _sub(1.0, c)
    txx, txy, txz = _mul(t, x * x), _mul(t, x * y), _mul(t, x * z)
    tyy, tyz, tzz = _mul(t, y * y), _mul(t, y * z), _mul(t, z * z)
    sx, sy, sz = _mul(s, x), _mul(s, y), _mul(s, z)
    return (
        (_add(txx, c), _sub(txy, sz), _add(txz, sy)),
        (_add(txy, sz), _add(tyy, c), _sub(tyz, sx)),
        (_sub(txz, sy), _add(tyz, sx), _add(tzz, c)),
    )


def _body_frames(lean: LeanArm, q) -> list[tuple]:
    """Chain.body_frames: per moving body (origin, rotation, joint axis, anchor), world."""
    ch = lean.chain
    x, rot = _vec(ch.base_pos), _mat(ch.base_rot)
    frames = []
    for i in range(6):
        axis, anchor = _vec(ch.axis[i]), _vec(ch.anchor[i])
        rot_pre = _mm(rot, _mat(ch.body_rot[i]))
        axis_w = _mv(rot_pre, axis)
        anchor_w = _vadd(_vadd(x, _mv(rot, _vec(ch.body_pos[i]))), _mv(rot_pre, anchor))
        rot = _mm(rot_pre, _rodrigues(axis, jnp.cos(q[i]), jnp.sin(q[i])))
        x = _vsub(anchor_w, _mv(rot, anchor))
        frames.append((x, rot, axis_w, anchor_w))
    return frames


def _mat_to_quat(m) -> tuple:
    """chain._mat_to_quat (Shepperd), then quat_canonical (w >= 0)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m
    tr = _sum(m00, m11, m22)
    cands = (
        (_add(1.0, tr), m21 - m12, m02 - m20, m10 - m01),
        (m21 - m12, 1.0 + m00 - m11 - m22, m01 + m10, m02 + m20),
        (m02 - m20, m01 + m10, 1.0 - m00 + m11 - m22, m12 + m21),
        (m10 - m01, m02 + m20, m12 + m21, 1.0 - m00 - m11 + m22),
    )
    # argmax([tr, m00, m11, m22]), first maximum wins. Nested: a later test runs only where
    # the earlier failed, which makes the shorter conditions equivalent (if m00 >= m11, m22
    # but not pick 0, then m00 > tr; likewise for m11 once picks 0 and 1 failed).
    pick0 = (tr >= m00) & (tr >= m11) & (tr >= m22)
    pick1 = (m00 >= m11) & (m00 >= m22)
    pick2 = m11 >= m22
    quat = [
        _where(pick0, c0, _where(pick1, c1, _where(pick2, c2, c3)))
        for c0, c1, c2, c3 in zip(*cands, strict=True)
    ]
    norm = _sqrt(_dot(quat, quat))
    quat = [v / norm for v in quat]
    flip = quat[0] < 0.0
    return tuple(_where(flip, -v, v) for v in quat)


# ------------------------------------------------------------------------- distances
def _segment_segment_distance(p1, q1, p2, q2, a, e):
    """lean.segment_segment_distance on 3-tuples; a, e: the constant squared lengths."""
    eps = 1e-12
    d1, d2, r = _vsub(q1, p1), _vsub(q2, p2), _vsub(p1, p2)
    f, c, b = _dot(d2, r), _dot(d1, r), _dot(d1, d2)
    denom = a * e - b * b
    s = _where(denom > eps, _clip((b * f - c * e) / _max(denom, eps), 0.0, 1.0), 0.0)
    t = (b * s + f) * (1.0 / max(e, eps))
    s = _where(t < 0.0, _clip(-c * (1.0 / max(a, eps)), 0.0, 1.0), s)
    s = _where(t > 1.0, _clip((b - c) * (1.0 / max(a, eps)), 0.0, 1.0), s)
    t = _clip(t, 0.0, 1.0)
    gap = _vsub(_vadd(p1, _vscale(d1, s)), _vadd(p2, _vscale(d2, t)))
    return _sqrt(_dot(gap, gap))


def _excess(p, h):
    """max(|p| - h, 0) sign(p) for h > 0, bit for bit, without abs and sign: p - h above
    the slab, p + h below it (fl(-p - h) = -fl(p + h)), 0 inside."""
    return _where(p > h, _sub(p, h), _where(p < -h, _add(p, h), 0.0))


def _segment_box_distance(a, b, half):
    """lean.segment_box_distance on 3-tuples (box frame), the reductions over its 8 knots
    (0, 1 and the 6 breaks) as running min / max."""
    d = _vsub(b, a)
    safe = [_where(_abs(di) > 1e-12, di, 1e-12) for di in d]
    breaks = [(h - ai) / si for h, ai, si in zip(half, a, safe, strict=True)]
    breaks += [(-h - ai) / si for h, ai, si in zip(half, a, safe, strict=True)]
    lo, hi, slope_lo, slope_hi = 0.0, 1.0, -INF, INF
    for knot in [0.0, 1.0, *(_clip(k, 0.0, 1.0) for k in breaks)]:
        p = _vadd(a, _vscale(d, knot))
        slope = _sum(*(_mul(_excess(pi, h), di) for pi, h, di in zip(p, half, d, strict=True)))
        down, up = slope <= 0.0, slope >= 0.0
        lo, hi = _max(lo, _where(down, knot, 0.0)), _min(hi, _where(up, knot, 1.0))
        slope_lo = _max(slope_lo, _where(down, slope, -INF))
        slope_hi = _min(slope_hi, _where(up, slope, INF))
    crossing = (hi > lo) & (slope_hi > slope_lo)
    rise = _where(crossing, slope_hi - slope_lo, 1.0)
    t = _where(crossing, lo - slope_lo * (hi - lo) / rise, lo)
    p = _vadd(a, _vscale(d, _clip(t, lo, hi)))
    out = [_max(_sub(_abs(pi), h), 0.0) for pi, h in zip(p, half, strict=True)]
    return _sqrt(_dot(out, out))


def _distances(lean: LeanArm, frames) -> list:
    """Signed distances of the capsule-capsule then the capsule-box pairs, as LeanArm.
    distances (one value each)."""
    segments: dict[tuple, tuple] = {}  # a capsule shared by several pairs is placed once

    def segment(body, pos, axis, half):
        key = (int(body), *_vec(pos), *_vec(axis), float(half))
        if key not in segments:
            x, rot = frames[int(body)][:2]
            centre = _vadd(x, _mv(rot, _vec(pos)))
            offset = _mv(rot, _vec(np.asarray(axis, np.float64) * half))
            segments[key] = (_vsub(centre, offset), _vadd(centre, offset))
        return segments[key]

    out = []
    for k in range(len(lean.cc_body)):
        (a0, a1), (b0, b1) = (
            segment(lean.cc_body[k, j], lean.cc_pos[k, j], lean.cc_axis[k, j], lean.cc_half[k, j])
            for j in (0, 1)
        )
        la, lb = (2.0 * float(lean.cc_half[k, 0])) ** 2, (2.0 * float(lean.cc_half[k, 1])) ** 2
        dist = _segment_segment_distance(a0, a1, b0, b1, la, lb)
        out.append(_sub(dist, float(lean.cc_radius[k].sum())))
    for k in range(len(lean.cb_body)):
        c0, c1 = segment(lean.cb_body[k], lean.cb_pos[k], lean.cb_axis[k], lean.cb_half[k])
        rot_t, box_pos = _mat(np.asarray(lean.box_rot[k]).T), _vec(lean.box_pos[k])
        local0, local1 = _mv(rot_t, _vsub(c0, box_pos)), _mv(rot_t, _vsub(c1, box_pos))
        dist = _segment_box_distance(local0, local1, _vec(lean.box_half[k]))
        out.append(_sub(dist, float(lean.cb_radius[k])))
    return out


# ----------------------------------------------------------------------------- public
def _full(v, like):
    """v as an array shaped like `like` (a constant output is broadcast)."""
    return jnp.full_like(like, v) if _is_const(v) else v


def soa_distances(lean: LeanArm, q) -> list:
    """q: 6 arrays (B,) -> the signed distances (m) of LeanArm.distances(q), capsule-capsule
    pairs then capsule-box pairs, each a (B,) array."""
    return [_full(d, q[0]) for d in _distances(lean, _body_frames(lean, q))]


def soa_pose(lean: LeanArm, q, *, collide: bool = True, jac: bool = False):
    """q: 6 arrays (B,) (float32, rad) -> (tcp: 3 arrays (B,) m, quat: 4 arrays (B,)
    (w, x, y, z) with w >= 0, collided: (B,) bool), as LeanArm.pose(q, collide) per
    element. With jac=True, a 4th item: the positional Jacobian as 3 rows of 6 arrays."""
    q = tuple(q)
    frames = _body_frames(lean, q)
    x, rot = frames[-1][:2]
    tcp = _vadd(x, _mv(rot, _vec(lean.chain.site)))
    quat = _mat_to_quat(rot)
    collided = jnp.zeros_like(q[0], dtype=bool)
    if collide:  # any pair penetrates: a chain of |
        for k, dist in enumerate(_distances(lean, frames)):
            collided = (dist < 0.0) if k == 0 else collided | (dist < 0.0)
    out = (tuple(_full(v, q[0]) for v in tcp), tuple(_full(v, q[0]) for v in quat), collided)
    if not jac:
        return out
    cols = [_cross(axis_w, _vsub(tcp, anchor_w)) for _, _, axis_w, anchor_w in frames]
    return (*out, tuple(tuple(_full(c[i], q[0]) for c in cols) for i in range(3)))


def arm_pose(lean: LeanArm, q: jax.Array, collide: bool = True) -> ArmPose:
    """`LeanArm.pose(q, collide)` through soa_pose: q (..., 6), any leading shape (one
    env, or a batch under vmap, where every op stays elementwise over the batch) ->
    ArmPose (the EnvConfig kinematics 'fused')."""
    tcp, quat, hit, jac = soa_pose(lean, [q[..., i] for i in range(6)], collide=collide, jac=True)
    rows = [jnp.stack(row, axis=-1) for row in jac]
    return ArmPose(jnp.stack(tcp, -1), jnp.stack(quat, -1), jnp.stack(rows, -2), hit)


def fused_pose(
    lean: LeanArm,
    q,
    *,
    block: int = 1024,
    backend: str = "jnp",
    interpret: bool = False,
    soa: bool = False,
    num_warps: int | None = None,
):
    """Batched soa_pose. q: (N, 6) array, or (soa=True) 6 arrays (N,). Returns tcp (N, 3),
    quat (N, 4), collided (N,) bool; with soa=True tuples of columns (3 and 4 (N,))
    instead, which spares a copy into (N, 3) / (N, 4).

    backend "jnp": soa_pose on the columns (XLA fuses it into one loop). "pallas": a
    pallas_call over a grid of N / block programs (N padded up to a multiple of `block`, a
    power of 2 for Triton), six (block,) inputs, eight (block,) outputs (collided as int32
    0/1), compiled by Pallas's Triton backend, named through its CompilerParams (jax 0.10
    sends a bare pallas_call to Mosaic GPU: jax_pallas_use_mosaic_gpu defaults to True),
    with `num_warps` (None: Pallas's default, 4);
    interpret=True runs the kernel with Pallas's interpreter (any device, the CPU)."""
    cols = tuple(jnp.asarray(c, jnp.float32) for c in q) if soa else None
    if cols is None:
        q = jnp.asarray(q, jnp.float32)
        cols = tuple(q[:, i] for i in range(6))
    if backend == "jnp":
        tcp, quat, hit = soa_pose(lean, cols)
    elif backend == "pallas":
        tcp, quat, hit = _pallas_pose(lean, cols, block, interpret, num_warps)
    else:
        raise ValueError(f"backend must be 'jnp' or 'pallas', got {backend!r}")
    if soa:
        return tcp, quat, hit
    return jnp.stack(tcp, axis=-1), jnp.stack(quat, axis=-1), hit


def _pallas_pose(lean: LeanArm, cols, block: int, interpret: bool, num_warps: int | None):
    from jax.experimental import pallas as pl  # here: nothing GPU-side at import time
    from jax.experimental.pallas import triton as pltriton

    if block < 1 or block & (block - 1):
        raise ValueError(f"block must be a power of 2 (a Triton block), got {block}")
    n = cols[0].shape[0]
    padded = -(-n // block) * block
    if padded != n:
        cols = tuple(jnp.pad(c, (0, padded - n)) for c in cols)

    def kernel(*refs):
        q_refs, out_refs = refs[:6], refs[6:]
        tcp, quat, hit = soa_pose(lean, tuple(r[...] for r in q_refs))
        for ref, v in zip(out_refs, (*tcp, *quat, hit.astype(jnp.int32)), strict=True):
            ref[...] = v

    spec = pl.BlockSpec((block,), lambda i: (i,))
    f32 = jax.ShapeDtypeStruct((padded,), jnp.float32)
    out = pl.pallas_call(
        kernel,
        out_shape=[f32] * 7 + [jax.ShapeDtypeStruct((padded,), jnp.int32)],
        grid=(padded // block,),
        in_specs=[spec] * 6,
        out_specs=[spec] * 8,
        interpret=interpret,
        compiler_params=pltriton.CompilerParams(num_warps=num_warps),
        name="fused_pose",
    )(*cols)
    out = [o[:n] for o in out] if padded != n else out
    return tuple(out[:3]), tuple(out[3:7]), out[7] != 0
