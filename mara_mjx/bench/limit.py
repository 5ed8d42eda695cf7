"""The `limit` study of `python -m mara_mjx.benchmark`: how far is one env step from the
device's ceilings?

Per (task, driver, environment count):
  * FLOPs, bytes accessed and transcendentals of one batched env step, per env, from
    XLA's cost analysis of the compiled step (`jax.jit(step).lower(...).compile()
    .cost_analysis()`), where `step` is exactly the body of the `env` study's timed scan
    (`BatchedEnv.step` with auto-reset, random joint targets drawn inside). These are
    XLA's estimates, not hardware counters: bytes are the operand and output sizes of
    each (fused) op, an upper bound on DRAM traffic where caches help and a lower bound
    where a kernel re-reads; and XLA counts the body of a `while` loop once, whatever
    its trip count. The optimised module's loops and their known trip counts are
    recorded (`loop_trip_counts`). The train driver has no loop of consequence (random
    numbers only, on some backends); the real driver's 10 physics substeps are a
    `lax.scan`, so for it the study also gives a loop-corrected estimate,
    train + substeps x (real - train), i.e. it takes the real step's counted cost beyond
    the train step (same task and size) as one substep's cost. The roofline uses the
    corrected numbers. Loops inside a substep (the constraint solver's Newton
    iterations, whose count is dynamic) are still counted once.
  * The device's ceilings, measured in the same run (compile excluded, best of
    `repeats` timed calls, each ended with block_until_ready): a float32 matmul at
    `Precision.HIGHEST` (no TF32; on GPUs this runs on the float32 units, the ceiling
    that matters for the env step's mostly elementwise float32 arithmetic), a bfloat16
    matmul (the tensor-core ceiling, for reference) and the memory bandwidth of a large
    elementwise `x + 1` (bytes read + written per second).
  * The roofline bound on env steps/s: min(float32 FLOP/s / FLOPs per env step,
    bandwidth / bytes per env step), which one limits, the measured env steps/s
    (`time_env`, the env study's timing) and the fraction of the bound reached.
"""

from __future__ import annotations

import dataclasses
import itertools
import re
import time
from collections.abc import Callable
from typing import Any, ClassVar, Literal

import jax
import jax.numpy as jnp

import mara_mjx
from mara_mjx.bench.env import EnvStudyConfig, variant
from mara_mjx.bench.runner import BenchConfig, Study
from mara_mjx.envs.batched import BatchedEnv
from mara_mjx.viz.plots import finish_figure


@dataclasses.dataclass(frozen=True)
class LimitConfig(BenchConfig):
    """The limit study's settings."""

    drivers: tuple[Literal["train", "real"], ...] = ("train", "real")
    """Drivers to measure."""
    sizes: tuple[int, ...] = (1024, 16384, 65536)
    """Environment counts for the train driver."""
    real_sizes: tuple[int, ...] = (16384,)
    """Environment counts for the real driver."""
    steps: int = 100
    """Env steps per timed call."""
    repeats: int = 5
    """Timed calls after the first."""
    matmul_size: int = 8192
    """n of the n x n matmuls that measure peak FLOP/s."""
    copy_size: int = 2**29
    """float32 elements of the x + 1 that measures memory bandwidth."""
    kinematics: tuple[Literal["lean", "fused", "mjx"], ...] = ("lean",)
    """The arm's pose passes to measure (EnvConfig.kinematics): 'lean' (the default),
    'fused' (its scalar form, fewer kernels) or 'mjx'."""
    reset_strategies: tuple[Literal["select", "cond"], ...] = ("select",)
    """BatchedEnv's auto-reset strategies to measure: 'select' (the default) or 'cond'."""

    QUICK: ClassVar[dict[str, Any]] = {
        "sizes": (4,),
        "real_sizes": (4,),
        "steps": 4,
        "repeats": 1,
        "matmul_size": 256,
        "copy_size": 2**20,
    }
    POSITIVE: ClassVar[tuple[str, ...]] = (
        "sizes",
        "real_sizes",
        "steps",
        "repeats",
        "matmul_size",
        "copy_size",
    )
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = EnvStudyConfig.CHOICES


def _best_time(fn: Callable[..., Any], args: tuple, repeats: int) -> float:
    """Best wall-clock of `repeats` calls after a first (compiling) call."""
    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best


def measure_ceilings(matmul_size: int, copy_size: int, repeats: int) -> dict[str, Any]:
    """Peak float32 (HIGHEST) and bfloat16 matmul FLOP/s and elementwise bandwidth."""
    n = matmul_size
    key_a, key_b = jax.random.split(jax.random.key(0))
    out: dict[str, Any] = {"matmul_size": n, "copy_elements": copy_size}
    for name, dtype, precision in (
        ("f32_matmul_flops_per_s", jnp.float32, jax.lax.Precision.HIGHEST),
        ("bf16_matmul_flops_per_s", jnp.bfloat16, jax.lax.Precision.DEFAULT),
    ):
        a = jax.random.normal(key_a, (n, n), dtype)
        b = jax.random.normal(key_b, (n, n), dtype)
        mm = jax.jit(lambda a, b, p=precision: jnp.matmul(a, b, precision=p))
        out[name] = 2.0 * n**3 / _best_time(mm, (a, b), repeats)
        del a, b
    x = jnp.zeros((copy_size,), jnp.float32)
    add = jax.jit(lambda x: x + 1.0)
    out["bytes_per_s"] = 2.0 * 4 * copy_size / _best_time(add, (x,), repeats)
    return out


# opcodes that launch no kernel of their own on a GPU (control flow, aliasing, tuples)
_NO_KERNEL = {
    "parameter",
    "constant",
    "get-tuple-element",
    "tuple",
    "bitcast",
    "while",
    "conditional",
    "call",
    "after-all",
    "partition-id",
    "replica-id",
    "opt-barrier",
    "add-dependency",
}


def kernel_count(hlo: str) -> int:
    """The instructions of an optimised HLO module that launch work: those of the entry,
    loop and branch computations (not of fused or applied computations), less control
    flow and aliasing. On a GPU each is about one kernel (a fusion, a library call, a
    copy); in a while loop, one per trip."""
    called = set(re.findall(r"(?:calls|to_apply)=%?([\w.-]+)", hlo))
    count, skip = 0, True
    for line in hlo.splitlines():
        head = re.match(r"^(?:ENTRY\s+)?%?([\w.-]+)\s.*\{\s*$", line)
        if head and not line.startswith(" "):
            skip = head.group(1) in called
            continue
        op = re.match(r"^\s+(?:ROOT\s+)?%?[\w.-]+\s*=\s*\S+(?:\s*\{[^}]*\})?\s+([\w-]+)\(", line)
        if not skip and op and op.group(1) not in _NO_KERNEL:
            count += 1
    return count


def step_cost(
    task: str, driver: str, num_envs: int, kinematics: str = "lean", reset_strategy: str = "select"
) -> dict[str, Any]:
    """XLA's cost analysis of one batched random-target env step (the env study's scan
    body), per env; plus the known trip counts of the module's while loops and its kernel
    count (fusions and library calls, each one kernel launch on a GPU). With 'cond' the
    reset branch is counted as if taken every step (XLA counts both branches)."""
    from mara_mjx.bench.env import make_step_body

    env = mara_mjx.make(task, driver=driver, kinematics=kinematics)
    benv = BatchedEnv(env, num_envs, reset_strategy=reset_strategy)
    state = jax.jit(benv.reset)(jax.random.key(0))
    body = make_step_body(benv)
    t0 = time.perf_counter()
    compiled = jax.jit(body).lower((state, jax.random.key(1)), None).compile()
    compile_s = time.perf_counter() - t0
    cost = compiled.cost_analysis()
    if isinstance(cost, list | tuple):  # older jax: one dict per module
        cost = cost[0]
    hlo = compiled.as_text()
    trips = [int(n) for n in re.findall(r'"known_trip_count":\{"n":"(\d+)"\}', hlo)]
    return {
        "flops": float(cost.get("flops", 0.0)) / num_envs,
        "bytes": float(cost.get("bytes accessed", 0.0)) / num_envs,
        "transcendentals": float(cost.get("transcendentals", 0.0)) / num_envs,
        "while_loops": len(re.findall(r"\swhile\(", hlo)),
        "kernels": kernel_count(hlo),
        "loop_trip_counts": trips,
        "analysis_compile_s": compile_s,
        "substeps": env.n_substeps if driver == "real" else 1,
    }


def limit_study(args: LimitConfig) -> list[dict[str, Any]]:
    """Cost per env step vs the measured ceilings, for every task, driver and size."""
    from mara_mjx.bench.env import time_env

    ceilings = measure_ceilings(args.matmul_size, args.copy_size, max(args.repeats, 3))
    print(
        f"ceilings: f32 matmul {ceilings['f32_matmul_flops_per_s'] / 1e12:.2f} TFLOP/s, "
        f"bf16 matmul {ceilings['bf16_matmul_flops_per_s'] / 1e12:.2f} TFLOP/s, "
        f"memory {ceilings['bytes_per_s'] / 1e9:.1f} GB/s",
        flush=True,
    )
    records = []
    train_costs: dict[tuple[str, str, str, int], dict[str, Any]] = {}
    for driver in args.drivers:
        sizes = args.sizes if driver == "train" else args.real_sizes
        for task, kin, rs in itertools.product(args.tasks, args.kinematics, args.reset_strategies):
            for n in sizes:
                cost = step_cost(task, driver, n, kin, rs)
                counted = {"flops": cost["flops"], "bytes": cost["bytes"]}
                if driver == "real":
                    if (task, kin, rs, n) not in train_costs:
                        train_costs[task, kin, rs, n] = step_cost(task, "train", n, kin, rs)
                    base, k = train_costs[task, kin, rs, n], cost["substeps"]
                    est = {q: base[q] + k * (cost[q] - base[q]) for q in ("flops", "bytes")}
                else:
                    train_costs[task, kin, rs, n] = cost
                    est = counted
                measured = time_env(
                    task, driver, n, args.steps, args.repeats, reset_strategy=rs, kinematics=kin
                )
                records.append(roofline(task, driver, n, cost, est, ceilings, measured))
                r = records[-1]
                bound, sps = r["bound_env_steps_per_s"] / 1e6, r["env_steps_per_s"] / 1e6
                print(
                    f"{task:20s} {driver:5s} {variant(r):11s} n={n:>7d}  {r['kernels']} kernels"
                    f"  {r['flops_per_env_step']:,.0f} FLOP  {r['bytes_per_env_step']:,.0f} B"
                    f"  bound {bound:.2f} M/s"
                    f" ({r['limited_by']})  measured {sps:.3f} M/s"
                    f"  = {100 * r['fraction_of_bound']:.1f}%",
                    flush=True,
                )
    return records


def roofline(
    task: str,
    driver: str,
    num_envs: int,
    cost: dict[str, Any],
    est: dict[str, float],
    ceilings: dict[str, Any],
    measured: dict[str, Any],
) -> dict[str, Any]:
    """One record: counted and estimated cost, bounds, measured rate, fraction."""
    flops, nbytes = est["flops"], est["bytes"]
    compute_bound = ceilings["f32_matmul_flops_per_s"] / flops if flops > 0 else float("inf")
    memory_bound = ceilings["bytes_per_s"] / nbytes if nbytes > 0 else float("inf")
    bound = min(compute_bound, memory_bound)
    sps = measured["env_steps_per_s"]
    return {
        "task": task,
        "driver": driver,
        "kinematics": measured["kinematics"],
        "reset_strategy": measured["reset_strategy"],
        "num_envs": num_envs,
        "substeps": cost["substeps"],
        "flops_per_env_step": flops,
        "bytes_per_env_step": nbytes,
        "xla_counted_flops_per_env_step": cost["flops"],
        "xla_counted_bytes_per_env_step": cost["bytes"],
        "transcendentals_per_env_step": cost["transcendentals"],
        "loop_corrected": driver == "real",
        "while_loops": cost["while_loops"],
        "kernels": cost["kernels"],
        "loop_trip_counts": cost["loop_trip_counts"],
        "flops_per_byte": flops / nbytes if nbytes > 0 else None,
        **ceilings,
        "compute_bound_env_steps_per_s": compute_bound,
        "memory_bound_env_steps_per_s": memory_bound,
        "bound_env_steps_per_s": bound,
        "limited_by": "compute" if compute_bound < memory_bound else "memory",
        "env_steps_per_s": sps,
        "fraction_of_bound": sps / bound,
        "achieved_flops_per_s": sps * flops,
        "achieved_bytes_per_s": sps * nbytes,
        "compile_s": measured["compile_s"],
        "analysis_compile_s": cost["analysis_compile_s"],
    }


def plot_limit(records: list[dict[str, Any]], title: str, path: Any) -> None:
    """Roofline: FLOP/s against FLOP/byte (log-log), the ceilings and each measured step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(7, 4.5))
    if records:
        c = records[0]
        xs = [r["flops_per_byte"] for r in records if r["flops_per_byte"]]
        lo, hi = min(xs + [0.1]) / 10, max(xs + [100.0]) * 10
        x = np.geomspace(lo, hi, 200)
        ceilings = (
            ("f32_matmul_flops_per_s", "-", "f32 (HIGHEST) matmul"),
            ("bf16_matmul_flops_per_s", "--", "bf16 matmul"),
        )
        for key, style, name in ceilings:
            roof = np.minimum(c[key], c["bytes_per_s"] * x)
            ax.plot(x, roof, style, color="k", linewidth=1, label=f"ceiling: {name} / memory")
        for i, r in enumerate(records):
            label = (
                f"{r['task']} {r['driver']} {variant(r)} n={r['num_envs']:,}: "
                f"{100 * r['fraction_of_bound']:.1f}% of bound"
            )
            ax.plot(
                r["flops_per_byte"], r["achieved_flops_per_s"], "o", color=f"C{i % 10}", label=label
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    xlabel = "arithmetic intensity (FLOP / byte, XLA cost analysis)"
    finish_figure(fig, ax, path, title, xlabel, "FLOP / s", legend_size=7)


def _m(x: float) -> str:
    return f"{x / 1e6:.3g} M"


LIMIT_TABLE: dict[str, Any] = {
    "title": "limit study: one env step against the device's measured ceilings",
    "columns": [
        ("task", lambda r: r["task"]),
        ("driver", lambda r: r["driver"]),
        ("kinematics", variant),
        ("envs", lambda r: f"{r['num_envs']:,}"),
        ("kernels", lambda r: str(r.get("kernels", ""))),
        ("FLOP / env step", lambda r: f"{r['flops_per_env_step']:,.0f}"),
        ("bytes / env step", lambda r: f"{r['bytes_per_env_step']:,.0f}"),
        ("FLOP / byte", lambda r: f"{r['flops_per_byte']:.2f}" if r["flops_per_byte"] else ""),
        ("bound (env steps/s)", lambda r: _m(r["bound_env_steps_per_s"])),
        ("limited by", lambda r: r["limited_by"]),
        ("measured (env steps/s)", lambda r: _m(r["env_steps_per_s"])),
        ("of bound", lambda r: f"{100 * r['fraction_of_bound']:.2f}%"),
    ],
    "notes": lambda records: (
        [
            "Ceilings measured in this run: float32 matmul (HIGHEST) "
            f"{records[0]['f32_matmul_flops_per_s'] / 1e12:.2f} TFLOP/s, bfloat16 matmul "
            f"{records[0]['bf16_matmul_flops_per_s'] / 1e12:.2f} TFLOP/s, memory "
            f"{records[0]['bytes_per_s'] / 1e9:.1f} GB/s. The bound uses float32 and memory.",
            "FLOPs and bytes are XLA's cost-analysis estimates (not hardware counters); XLA "
            "counts a while-loop body once, so the real driver's numbers are loop-corrected "
            "estimates: train + substeps x (real - train) (`xla_counted_*` in the JSON are "
            "the raw counts); loops inside a substep (the constraint solver's iterations) "
            "are still counted once, so the real driver's cost is, if anything, "
            "underestimated and its bound overestimated. Kernels: the launching instructions "
            "of one step's optimised module (`kernel_count`); a 'cond' step counts its "
            "reset branch, which runs only where an episode ended.",
        ]
        if records
        else []
    ),
    "plot": plot_limit,
}


STUDY = Study("limit", LimitConfig, limit_study, LIMIT_TABLE, "one env step against the roofline")
