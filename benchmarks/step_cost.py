"""Where the train driver's env step spends its FLOPs and bytes (XLA cost analysis).

    python benchmarks/step_cost.py --envs 4096 --steps 20          # any device
    python benchmarks/step_cost.py --envs 65536 --steps 100 --out step_cost.json   # a GPU

For one task (default MARACollisionOrient, train driver, `--kinematics` lean or mjx) each
variant below is jitted over `--envs` environments and XLA's cost analysis of the
compiled program (`jit(f).lower(...).compile().cost_analysis()`) is divided by the number
of envs: FLOPs, transcendentals and bytes accessed per env step, and the number of
non-trivial instructions of the entry computation (on a GPU about the number of kernels
one step launches). Variants isolate the pieces:

  kinematics     the pose pass without collision (TCP pose and Jacobian)
  pose           the pose pass with the 24 pair distances (the collided bit)
  reset          vmap(env.reset): noise draw, kinematics, observation, metrics
  env_step       vmap(env.step) (lean_check.py's `time` mode, without its random actions)
  env_step_core  the same with the metrics dropped from the output (XLA prunes their work)
  auto_reset     BatchedEnv.auto_reset alone (only with the elementwise patch of
                 results/lean/, which made it a method; not adopted: NOTES section 27)
  batched        BatchedEnv.step: env_step + auto_reset + episode statistics, what the
                 PPO rollout calls each step
  random_actions the benchmark's uniform draw of (envs, 6) actions

`--top K` lists the K entry instructions of `batched` (by default; `--hlo VARIANT`) that
move the most bytes (operands + result). Then, unless `--no-time`, steady-state env
steps/s on the present device: `batched` and `env_step` scanned over `--steps` with
actions from a small precomputed table (no RNG in the loop), and lean_check.py's loop
(random actions + env_step); compile time apart, median of `--repeats` calls.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import mara_mjx
from mara_mjx.envs.batched import BatchedEnv

TRIVIAL = {"parameter", "constant", "bitcast", "get-tuple-element", "tuple", "copy-start",
           "copy-done", "after-all", "partition-id", "replica-id"}  # fmt: skip
_BYTES = {"f64": 8, "s64": 8, "u64": 8, "f32": 4, "s32": 4, "u32": 4, "f16": 2, "bf16": 2,
          "s16": 2, "u16": 2, "s8": 1, "u8": 1, "pred": 1}  # fmt: skip
_SHAPE = re.compile(r"\b(f64|s64|u64|f32|s32|u32|f16|bf16|s16|u16|s8|u8|pred)\[([\d,]*)\]")
_INSTR = re.compile(r"^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=\s*(.+?)\s+([\w\-]+)\((.*)$")


def shape_bytes(text: str) -> int:
    """Bytes of every array shape written in `text` (an HLO result type, maybe a tuple)."""
    total = 0
    for dtype, dims in _SHAPE.findall(text):
        total += _BYTES[dtype] * int(np.prod([int(d) for d in dims.split(",") if d] or [1]))
    return total


def entry_instructions(hlo: str) -> list[dict]:
    """The compiled module's entry computation: name, opcode, result bytes, operand bytes,
    and for fusions their kind and the op_name of their metadata."""
    body = hlo[hlo.index("\nENTRY") :]
    body = body[: body.index("\n}")]
    sizes, rows = {}, []
    for line in body.splitlines()[1:]:
        m = _INSTR.match(line)
        if not m:
            continue
        name, rtype, opcode, rest = m.groups()
        sizes[name] = shape_bytes(rtype)
        operands = re.findall(r"%([\w.\-]+)", rest.split("), ")[0])
        kind = re.search(r"kind=(\w+)", rest)
        op_name = re.search(r'op_name="([^"]+)"', rest)
        rows.append({
            "name": name,
            "opcode": opcode,
            "kind": kind.group(1) if kind else "",
            "result_bytes": sizes[name],
            "operand_bytes": sum(sizes.get(o, 0) for o in operands),
            "op_name": op_name.group(1) if op_name else "",
        })  # fmt: skip
    return rows


def cost(fn, args, n: int) -> tuple[dict, str]:
    """XLA's cost analysis of jit(fn)(*args) per env, and the compiled HLO text."""
    compiled = jax.jit(fn).lower(*args).compile()
    ca = compiled.cost_analysis()
    ca = ca[0] if isinstance(ca, list) else ca
    hlo = compiled.as_text()
    ops = [r for r in entry_instructions(hlo) if r["opcode"] not in TRIVIAL]
    return {
        "flops": ca.get("flops", 0.0) / n,
        "transcendentals": ca.get("transcendentals", 0.0) / n,
        "bytes_accessed": ca.get("bytes accessed", 0.0) / n,
        "entry_ops": len(ops),
        "fusions": sum(r["opcode"] == "fusion" for r in ops),
    }, hlo


def variants(env, benv: BatchedEnv, n: int) -> dict:
    """name -> (function, example arguments)."""
    lean = env.arm.lean
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), n))
    bstate = benv.reset(jax.random.key(0))
    q = jnp.zeros((n, 6), jnp.float32)
    keys = jax.random.split(jax.random.key(1), n)
    params = bstate.env_state.params
    done = jnp.arange(n) % 7 == 0
    lo, hi = jnp.asarray(env.joint_lower), jnp.asarray(env.joint_upper)
    kin = env.kinematics

    def core(s, a):
        out = jax.vmap(env.step)(s, a)
        return out.replace(metrics=s.metrics)

    return (
        {
            "kinematics": (jax.vmap(lambda q: env.arm.pose_with(q, kin, collide=False)), (q,)),
            "pose": (jax.vmap(lambda q: env.arm.pose_with(q, kin)), (q,)),
            "reset": (jax.vmap(env.reset), (keys, params)),
            "env_step": (jax.vmap(env.step), (states, q)),
            "env_step_core": (core, (states, q)),
            "batched": (benv.step, (bstate, q)),
            "random_actions": (
                lambda k: jax.random.uniform(k, (n, 6), minval=lo, maxval=hi),
                (jax.random.key(2),),
            ),
        }
        | (  # a BatchedEnv with an auto_reset method (the tried elementwise patch's)
            {"auto_reset": (benv.auto_reset, (bstate.env_state, done))}
            if hasattr(benv, "auto_reset")
            else {}
        )
        | ({"lean_distances": (jax.vmap(lean.distances), (q,))} if kin == "lean" else {})
    )


def timing(env, benv: BatchedEnv, n: int, steps: int, repeats: int) -> dict:
    """Env steps/s of three scanned loops (module docstring), compile apart."""
    lo, hi = np.asarray(env.joint_lower), np.asarray(env.joint_upper)
    table = np.random.default_rng(0).uniform(lo, hi, (8, n, 6)).astype(np.float32)
    table = jnp.asarray(table)
    lo, hi = jnp.asarray(lo), jnp.asarray(hi)

    def from_table(step):
        def run(state):
            def body(s, t):
                return step(s, table[t % table.shape[0]]), None

            return jax.lax.scan(body, state, jnp.arange(steps))[0]

        return jax.jit(run)

    def lean_check_loop(state, key):
        def body(s, k):
            a = jax.random.uniform(k, (n, 6), minval=lo, maxval=hi)
            return jax.vmap(env.step)(s, a), None

        return jax.lax.scan(body, state, jax.random.split(key, steps))[0]

    loops = {
        "batched": (from_table(benv.step), lambda: benv.reset(jax.random.key(0))),
        "env_step": (
            from_table(jax.vmap(env.step)),
            lambda: jax.vmap(env.reset)(jax.random.split(jax.random.key(0), n)),
        ),
        "lean_check_loop": (
            jax.jit(lean_check_loop),
            lambda: jax.vmap(env.reset)(jax.random.split(jax.random.key(0), n)),
        ),
    }
    out = {}
    for name, (fn, init) in loops.items():
        extra = (jax.random.key(1),) if name == "lean_check_loop" else ()
        state = jax.block_until_ready(init())
        t0 = time.perf_counter()
        state = jax.block_until_ready(fn(state, *extra))
        first = time.perf_counter() - t0
        ts = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            state = jax.block_until_ready(fn(state, *extra))
            ts.append(time.perf_counter() - t0)
        med = statistics.median(ts)
        out[name] = {"compile_and_first_call_s": first, "call_s": med,
                     "env_steps_per_s": n * steps / med}  # fmt: skip
        rate = f"{n * steps / med / 1e6:9.3f} M env steps/s"
        print(f"  {name:16s} {rate}   (first call {first:.1f} s, median call {med * 1e3:.1f} ms)")
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--kinematics", default="lean", choices=("lean", "mjx"))
    p.add_argument("--envs", type=int, default=4096)
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--top", type=int, default=12)
    p.add_argument("--hlo", default="batched", help="variant whose largest ops --top lists")
    p.add_argument("--no-time", action="store_true")
    p.add_argument("--out", default="")
    args = p.parse_args()
    env = mara_mjx.make(args.task, kinematics=args.kinematics)
    benv = BatchedEnv(env, args.envs, devices=1)
    n = args.envs
    out = {"command": "python " + " ".join(sys.argv), "jax": jax.__version__,
           "device": str(jax.devices()[0]), "task": args.task, "envs": n,
           "kinematics": args.kinematics,
           "per_env_step": {}}  # fmt: skip
    print(f"{args.task} ({args.kinematics}), {n} envs, {out['device']}, jax {jax.__version__}")
    print(f"{'variant':16s} {'FLOP':>9s} {'transc':>7s} {'bytes':>9s} {'ops':>5s} {'fusions':>7s}")
    hlo = ""
    for name, (fn, fargs) in variants(env, benv, n).items():
        row, text = cost(fn, fargs, n)
        hlo = text if name == args.hlo else hlo
        out["per_env_step"][name] = row
        cols = f"{row['flops']:9.0f} {row['transcendentals']:7.1f} {row['bytes_accessed']:9.0f}"
        print(f"{name:16s} {cols} {row['entry_ops']:5d} {row['fusions']:7d}", flush=True)
    if hlo and args.top:
        ops = [r for r in entry_instructions(hlo) if r["opcode"] not in TRIVIAL]
        ops.sort(key=lambda r: -(r["result_bytes"] + r["operand_bytes"]))
        out["largest_ops"] = ops[: args.top]
        print(f"\n{args.hlo}: the {args.top} entry ops moving the most bytes (per env)")
        for r in ops[: args.top]:
            moved = (r["result_bytes"] + r["operand_bytes"]) / n
            label = f"{r['opcode']}:{r['kind']}" if r["kind"] else r["opcode"]
            print(f"  {moved:8.0f} B  {label:18s} {r['name'][:28]:28s} {r['op_name'][-60:]}")
    if not args.no_time:
        print(f"\ntiming: {args.steps} steps per call, median of {args.repeats} calls")
        out["timing"] = timing(env, benv, n, args.steps, args.repeats)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
