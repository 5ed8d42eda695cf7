"""The train driver's pose pass three ways: vmapped LeanArm.pose, and the fused
structure-of-arrays pass (mara_mjx/envs/fused_pose.py) through XLA and as a Pallas kernel.

    python benchmarks/fused_pose_bench.py                          # a GPU: 64 Ki, 256 Ki, 1 Mi
    python benchmarks/fused_pose_bench.py --sizes 4096 16384 --steps 10 --repeats 3  # a CPU

Variants (each maps q (N, 6) to tcp (N, 3), quat (N, 4), collided (N,); the Jacobian,
which `fused_pose` does not compute, is dropped from `lean`'s output so XLA prunes it):

  lean        jax.vmap(LeanArm.pose)
  jnp         fused_pose(backend="jnp"): one elementwise graph
  pallas      fused_pose(backend="pallas"): a Pallas Triton kernel (on a CPU Pallas's
              interpreter runs it); skipped, with the reason recorded, if it fails to lower
  jnp_soa,    the same two with q as 6 columns (N,) and the outputs as columns (N,)
  pallas_soa  (fused_pose's soa=True): no transposes or stacks around the pass

Per size N: XLA's cost analysis of one compiled pass (not the scan) per pose (FLOPs,
bytes accessed; a Pallas custom call is opaque to it, so expect no FLOPs for its work
and only its operands' and results' bytes; with Pallas's interpreter, on a CPU, it counts
one grid step of the interpreter's loop), the bytes of the pass's inputs and outputs
(the least it can move), the non-trivial instructions of the optimised HLO's entry
computation and how many of them are fusions (on a GPU about the kernels one pass
launches; step_cost.py's count), then the time of a jitted `lax.scan` of `--steps`
passes, each on q = q0 + 1e-3 k (k the step: nothing can be hoisted out of the loop)
with the last outputs as the carry: compile apart, median of `--repeats` calls,
block_until_ready. The collided bits of all variants on the first size's batch (uniform
in the joint box) are compared with `lean`'s; disagreements are counted, and those where
the smallest signed pair distance is within 1e-6 m of 0 (float32 rounding can flip them)
apart.
Everything goes to `--out` (JSON, rewritten after every row, so a run cut short keeps its
finished rows; a file other than this script's own earlier report is replaced only with
`--overwrite`) and a table.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from importlib.metadata import version
from pathlib import Path

# as the CLIs (cli.common.configure_jax): no TF32 in lean's 3x3 products on a GPU
os.environ.setdefault("JAX_DEFAULT_MATMUL_PRECISION", "highest")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import mara_mjx  # noqa: E402
from mara_mjx.envs.fused_pose import fused_pose  # noqa: E402
from mara_mjx.envs.lean import LeanArm  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from step_cost import TRIVIAL, entry_instructions  # noqa: E402

VARIANTS = ("lean", "jnp", "pallas", "jnp_soa", "pallas_soa")


def pose_fns(lean: LeanArm, block: int, interpret: bool, num_warps: int | None) -> dict:
    """name -> (pose function, whether it takes and returns columns)."""

    def lean_pose(q):
        p = jax.vmap(lean.pose)(q)
        return p.tcp_pos, p.tcp_quat, p.collided

    def fused(backend, soa):
        kw = {"block": block, "interpret": interpret, "num_warps": num_warps}
        return lambda q: fused_pose(lean, q, backend=backend, soa=soa, **kw)

    return {
        "lean": (lean_pose, False),
        "jnp": (fused("jnp", False), False),
        "pallas": (fused("pallas", False), False),
        "jnp_soa": (fused("jnp", True), True),
        "pallas_soa": (fused("pallas", True), True),
    }


def as_input(q: np.ndarray, soa: bool):
    q = jnp.asarray(q, jnp.float32)
    return tuple(q[:, i] for i in range(6)) if soa else q


def as_rows(out, soa: bool):
    """(tcp (N, 3), quat (N, 4), collided (N,)) as numpy, whatever the layout."""
    tcp, quat, hit = out
    if soa:
        tcp, quat = jnp.stack(tcp, -1), jnp.stack(quat, -1)
    return np.asarray(tcp), np.asarray(quat), np.asarray(hit)


def scanned(pose, steps: int):
    """q0 -> the outputs of the last of `steps` passes, pass k on q0 + 1e-3 k."""

    def run(q0):
        def body(_, k):
            shift = k.astype(jnp.float32) * 1e-3
            return pose(jax.tree.map(lambda c: c + shift, q0)), None

        shapes = jax.eval_shape(pose, q0)
        init = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        return jax.lax.scan(body, init, jnp.arange(steps))[0]

    return jax.jit(run)


def cost(pose, q0, n: int) -> dict:
    """XLA's cost analysis of one compiled pass, per pose, and its entry instructions."""
    compiled = jax.jit(pose).lower(q0).compile()
    ca = compiled.cost_analysis()
    ca = (ca[0] if isinstance(ca, list) else ca) or {}
    ops = [r for r in entry_instructions(compiled.as_text()) if r["opcode"] not in TRIVIAL]
    io = jax.tree.leaves((q0, jax.eval_shape(pose, q0)))
    return {
        "io_bytes_per_pose": sum(x.size * x.dtype.itemsize for x in io) / n,
        "flops_per_pose": ca.get("flops", 0.0) / n,
        "transcendentals_per_pose": ca.get("transcendentals", 0.0) / n,
        "bytes_accessed_per_pose": ca.get("bytes accessed", 0.0) / n,
        "entry_ops": len(ops),
        "fusions": sum(r["opcode"] == "fusion" for r in ops),
        "custom_calls": sum(r["opcode"] == "custom-call" for r in ops),
    }


def timing(pose, q0, n: int, steps: int, repeats: int) -> dict:
    fn = scanned(pose, steps)
    t0 = time.perf_counter()
    compiled = fn.lower(q0).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(q0))  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(q0))
        ts.append(time.perf_counter() - t0)
    med = statistics.median(ts)
    return {"compile_s": compile_s, "call_s": med, "call_s_all": ts,
            "poses_per_s": n * steps / med}  # fmt: skip


def agreement(lean: LeanArm, fns: dict, q: np.ndarray, ok: list[str]) -> dict:
    """Each variant's collided bits (and poses) against lean's on the batch q."""

    def smallest(qi):
        cc, cb = lean.distances(qi)
        return jnp.minimum(jnp.min(cc), jnp.min(cb))

    dmin = np.asarray(jax.jit(jax.vmap(smallest))(jnp.asarray(q)))
    outs = {}
    for name in ok:
        pose, soa = fns[name]
        outs[name] = as_rows(jax.jit(pose)(as_input(q, soa)), soa)
    ref_tcp, ref_quat, ref_hit = outs["lean"]
    band = np.abs(dmin) <= 1e-6
    rows = {"configurations": len(q), "lean_collided_fraction": float(ref_hit.mean()),
            "within_1e-6_m_of_contact": int(band.sum())}  # fmt: skip
    for name, (tcp, quat, hit) in outs.items():
        if name == "lean":
            continue
        differ = hit != ref_hit
        rows[name] = {
            "collided_disagreements": int(differ.sum()),
            "of_them_within_1e-6_m": int((differ & band).sum()),
            "max_abs_tcp_diff_m": float(np.abs(tcp - ref_tcp).max()),
            "max_abs_quat_diff": float(np.abs(quat - ref_quat).max()),
        }
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[65536, 262144, 1048576])
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--block", type=int, default=1024, help="Pallas block (a power of 2)")
    p.add_argument("--num-warps", type=int, default=None, help="Triton warps (default 4)")
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs/fused_pose.json")
    p.add_argument("--overwrite", action="store_true", help="--out may replace any file")
    args = p.parse_args()
    from mara_mjx.cli.common import UserError
    from mara_mjx.runtime import files, outputs

    try:  # a new file or this script's own earlier output, checked before the work
        ours = lambda path: outputs.written_by(path, "python benchmarks/fused_pose_bench.py")  # noqa: E731
        outputs.check_output(args.out, "--out report", ours, args.overwrite)
    except UserError as e:
        raise SystemExit(f"error: {e}") from None

    env = mara_mjx.make("MARACollisionOrient", driver="train")
    lean = LeanArm.from_model(env.arm.mj_model)
    device = jax.devices()[0]
    interpret = device.platform == "cpu"
    fns = pose_fns(lean, args.block, interpret, args.num_warps)
    out = {
        "command": "python benchmarks/fused_pose_bench.py " + " ".join(sys.argv[1:]),
        "jax": jax.__version__,
        "jaxlib": version("jaxlib"),
        "device": str(device),
        "device_kind": getattr(device, "device_kind", ""),
        "platform": device.platform,
        "matmul_precision": os.environ["JAX_DEFAULT_MATMUL_PRECISION"],
        "steps": args.steps,
        "repeats": args.repeats,
        "block": args.block,
        "num_warps": args.num_warps,
        "pallas_interpret": interpret,
        "skipped": {},
        "sizes": {},
    }
    print(f"{out['device']} ({out['device_kind']}), jax {jax.__version__}, "
          f"{args.steps} passes per call, median of {args.repeats} calls"
          + (", Pallas interpreted" if interpret else ""))  # fmt: skip
    head = f"{'N':>8s} {'variant':11s} {'Mposes/s':>9s} {'call ms':>8s} {'compile s':>9s}"
    print(head + f" {'FLOP/pose':>9s} {'B/pose':>8s} {'IO B':>5s} {'ops':>4s} {'fusions':>7s}")
    rng = np.random.default_rng(args.seed)
    ok = []
    for n in args.sizes:
        q = rng.uniform(env.joint_lower, env.joint_upper, (n, 6)).astype(np.float32)
        rows = out["sizes"][str(n)] = {}
        for name in args.variants:
            if name in out["skipped"]:
                continue
            pose, soa = fns[name]
            q0 = as_input(q, soa)
            try:
                row = cost(pose, q0, n)
                row.update(timing(pose, q0, n, args.steps, args.repeats))
            except Exception as e:  # a Pallas kernel that does not lower here
                out["skipped"][name] = f"{type(e).__name__}: {e}"[:2000]
                print(f"{n:8d} {name:11s} skipped: {out['skipped'][name][:200]}", flush=True)
                continue
            rows[name] = row
            files.write_atomic(args.out, json.dumps(out, indent=1))  # a cut run keeps its rows
            ok += [name] if name not in ok else []
            print(f"{n:8d} {name:11s} {row['poses_per_s'] / 1e6:9.3f} {row['call_s'] * 1e3:8.2f}"
                  f" {row['compile_s']:9.1f} {row['flops_per_pose']:9.0f}"
                  f" {row['bytes_accessed_per_pose']:8.1f} {row['io_bytes_per_pose']:5.0f}"
                  f" {row['entry_ops']:4d}"
                  f" {row['fusions']:7d}", flush=True)  # fmt: skip
    if "lean" in ok:
        n = args.sizes[0]
        q = np.random.default_rng(args.seed).uniform(env.joint_lower, env.joint_upper, (n, 6))
        out["agreement"] = agreement(lean, fns, q.astype(np.float32), ok)
        print(f"\ncollided vs lean on {n} configurations: " + ", ".join(
            f"{k} {v['collided_disagreements']} ({v['of_them_within_1e-6_m']} within 1e-6 m)"
            for k, v in out["agreement"].items() if isinstance(v, dict)))  # fmt: skip
    files.write_atomic(args.out, json.dumps(out, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
