"""2 processes x 1 GPU against 1 process x 2 GPUs on the same global batch (the train CLI).

On a host with 2 GPUs (the device machine 'nvidia-h200-x2', carrying .whl; about 3
minutes), from the repository root:

    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir \
        --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PWD || exit 1
    export PYTHONUNBUFFERED=1 NCCL_NVLS_ENABLE=0; nvidia-smi -L > $OUT/gpus.txt
    timeout 330 python3 benchmarks/multiprocess.py --out $OUT/multiprocess --timeout 150

(results: benchmarks/results/multiprocess/). The processes inherit the environment (there:
NCCL_NVLS_ENABLE=0, NVLink multicast off, as the device machines require).

runs `python -m mara_mjx.train` twice, one after the other, with the same flags (the
'default' preset, MARA, --num_envs 4096 = 2048 per GPU, --updates updates, a checkpoint
at the end only, no evaluation, plots or TensorBoard):

    single   CUDA_VISIBLE_DEVICES=0,1  ... --devices 2
    multi    CUDA_VISIBLE_DEVICES=i    ... --coordinator localhost:PORT --num_processes 2
                                           --process_id i          (i = 0, 1, in parallel)

and compares them: env steps/s (median over the jitted calls of --updates_per_call updates
after the first, which compiles; from progress.csv), time per update, the command's
wall-clock time, and the final checkpoints (parameters and the whole training state:
max |difference|, also relative to the largest |parameter|). The issue's criterion: multi
within 10% of single in env steps/s, and matching parameters.

Writes to --out: multiprocess.json (everything, with the exact commands), multiprocess.md
(the table) and logs.tar.gz (each process's output, progress.csv and config.json). The run
folders themselves (checkpoints) stay in a temporary folder.

`--platform cpu` runs the same comparison on CPU devices (XLA's forced host device count
instead of CUDA_VISIBLE_DEVICES), as a smoke test with tiny settings, e.g.
`--platform cpu --num_envs 8 --num_steps 8 --num_minibatches 2 --updates 4
--updates_per_call 2`.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import socket
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def train_flags(args: argparse.Namespace) -> list[str]:
    """The flags both layouts share."""
    total = args.updates * args.num_envs * args.num_steps
    flags = [
        "--env", args.env,
        "--num_envs", str(args.num_envs),
        "--num_steps", str(args.num_steps),
        "--total_timesteps", str(total),
        "--updates_per_call", str(args.updates_per_call),
        "--checkpoint_every", str(args.updates),
        "--evaluate", "false",
        "--plots", "false",
        "--tensorboard", "false",
        "--progress", "false",
    ]  # fmt: skip
    if args.num_minibatches:
        flags += ["--num_minibatches", str(args.num_minibatches)]
    return flags + list(args.extra)


def device_env(platform: str, index: str, count: int) -> dict[str, str]:
    """Environment variables that give a process the devices `index` ('0,1' or '1')."""
    if platform == "cpu":
        return {
            "JAX_PLATFORMS": "cpu",
            "XLA_FLAGS": f"--xla_force_host_platform_device_count={count}",
        }
    return {"CUDA_VISIBLE_DEVICES": index}


def run_layout(
    name: str, args: argparse.Namespace, work: Path, common: list[str]
) -> dict[str, Any]:
    """Run one layout; its processes' commands, outputs, exit codes and wall time."""
    out = work / name
    if name == "single":
        launches = [(device_env(args.platform, "0,1", 2), ["--devices", "2"])]
    else:
        port = free_port()
        launches = [
            (
                device_env(args.platform, str(i), 1),
                ["--coordinator", f"localhost:{port}", "--num_processes", "2"]
                + ["--process_id", str(i), "--heartbeat_timeout", "30"],
            )
            for i in range(2)
        ]
    procs, commands = [], []
    start = time.monotonic()
    for i, (extra_env, flags) in enumerate(launches):
        argv = [sys.executable, "-m", "mara_mjx.train", *common, "--out", str(out), *flags]
        env = {**os.environ, **extra_env}
        commands.append(" ".join(f"{k}={v}" for k, v in extra_env.items()) + " " + " ".join(argv))
        log = open(work / f"{name}-{i}.log", "w")
        proc = subprocess.Popen(argv, cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
        procs.append((proc, log))
    codes = []
    for p, log in procs:
        try:
            codes.append(p.wait(timeout=max(1.0, args.timeout - (time.monotonic() - start))))
        except subprocess.TimeoutExpired:
            for q, _ in procs:
                q.kill()
            codes.append(None)
        log.close()
    wall = time.monotonic() - start
    result = {"commands": commands, "exit_codes": codes, "wall_s": wall, "out": str(out)}
    if any(c != 0 for c in codes):
        tails = [
            f"--- {name} process {i}:\n" + (work / f"{name}-{i}.log").read_text()[-2500:]
            for i in range(len(codes))
        ]
        raise SystemExit(
            f"{name}: exit codes {codes}; the processes' outputs end with:\n" + "\n".join(tails)
        )
    result.update(throughput(out / "progress.csv", args))
    return result


def throughput(progress: Path, args: argparse.Namespace) -> dict[str, Any]:
    """env steps/s per jitted call from progress.csv (rows of one call share time_s)."""
    with open(progress) as f:
        rows = list(csv.DictReader(f))
    calls: dict[str, float] = {}
    for row in rows:
        calls.setdefault(row["time_s"], float(row["steps_per_s"]))
    per_call = list(calls.values())
    timed = per_call[1:] or per_call  # the first call compiles
    median = statistics.median(timed)
    steps_per_update = args.num_envs * args.num_steps
    return {
        "updates": len(rows),
        "calls": len(per_call),
        "steps_per_s_per_call": per_call,
        "env_steps_per_s": median,
        "time_per_update_ms": 1000.0 * steps_per_update / median,
        "first_call_steps_per_s": per_call[0],
        "time_s_last_row": float(rows[-1]["time_s"]),
        "reward_mean": [float(r["reward_mean"]) for r in rows],
    }


def compare_checkpoints(a: Path, b: Path) -> dict[str, Any]:
    from mara_mjx.ppo import checkpoint as ckpt

    (arrays_a, meta_a), (arrays_b, _) = ckpt.load_checkpoint(a), ckpt.load_checkpoint(b)
    params = [k for k in arrays_a if k.startswith("params/")]
    scale = max(float(np.abs(arrays_a[k]).max()) for k in params)

    def diff(keys) -> float:
        return max(
            float(np.abs(arrays_a[k].astype(np.float64) - arrays_b[k].astype(np.float64)).max())
            for k in keys
        )

    state = [k for k in arrays_a if k != "__meta__" and arrays_a[k].dtype.kind in "fiu"]
    return {
        "checkpoint": a.name,
        "update": meta_a["progress"]["update"],
        "param_max_abs": float(scale),
        "param_max_abs_diff": diff(params),
        "param_max_rel_diff": diff(params) / scale,
        "state_max_abs_diff": diff(state),
        "identical": all(np.array_equal(arrays_a[k], arrays_b[k]) for k in arrays_a),
        "versions": meta_a.get("versions"),
    }


def markdown(report: dict[str, Any]) -> str:
    s, m, c = report["single"], report["multi"], report["params"]
    ratio = report["multi_over_single"]
    lines = [
        "# 2 processes x 1 GPU vs 1 process x 2 GPUs (same global batch)",
        "",
        f"{report['env']}, 'default' preset, {report['num_envs']} envs x "
        f"{report['num_steps']} steps per update (global), {report['updates']} updates in "
        f"calls of {report['updates_per_call']}; devices: {c['versions'].get('devices')}; "
        f"jax {c['versions'].get('jax')}.",
        "",
        "| layout | env steps/s (median of calls after the first) | time per update | "
        "command wall-clock |",
        "|---|---|---|---|",
        f"| 1 process x 2 GPUs | {s['env_steps_per_s'] / 1e6:.3f} M | "
        f"{s['time_per_update_ms']:.2f} ms | {s['wall_s']:.1f} s |",
        f"| 2 processes x 1 GPU | {m['env_steps_per_s'] / 1e6:.3f} M | "
        f"{m['time_per_update_ms']:.2f} ms | {m['wall_s']:.1f} s |",
        "",
        f"2 processes / 1 process: {ratio:.3f} of the env steps/s "
        f"({'within' if ratio >= 0.9 else 'NOT within'} 10%).",
        "",
        f"Final checkpoint ({c['checkpoint']}, update {c['update']}): parameters differ by at "
        f"most {c['param_max_abs_diff']:.3g} ({c['param_max_rel_diff']:.3g} of the largest "
        f"|parameter|, {c['param_max_abs']:.3g}); the whole training state by at most "
        f"{c['state_max_abs_diff']:.3g}; bitwise identical: {c['identical']}. "
        f"Mean reward per update differs by at most {report['reward_max_abs_diff']:.3g}.",
        "",
        "Commands:",
        "",
        "```",
        *s["commands"],
        *m["commands"],
        "```",
        "",
    ]
    return "\n".join(lines)


def compare(args: argparse.Namespace, work: Path, common: list[str]) -> dict[str, Any]:
    """Run both layouts and compare them (the report)."""
    results = {}
    for name in args.order:
        print(f"running {name} ...", flush=True)
        results[name] = run_layout(name, args, work, common)
        print(f"{name}: {results[name]['env_steps_per_s'] / 1e6:.3f} M env steps/s", flush=True)
    final = f"checkpoints/ckpt_{args.updates:08d}.npz"
    params = compare_checkpoints(work / "single" / final, work / "multi" / final)
    rewards = [results[n]["reward_mean"] for n in ("single", "multi")]
    return {
        "env": args.env,
        "num_envs": args.num_envs,
        "num_steps": args.num_steps,
        "updates": args.updates,
        "updates_per_call": args.updates_per_call,
        "platform": args.platform,
        "order": args.order,
        "single": results["single"],
        "multi": results["multi"],
        "multi_over_single": results["multi"]["env_steps_per_s"]
        / results["single"]["env_steps_per_s"],
        "params": params,
        "reward_max_abs_diff": float(np.max(np.abs(np.subtract(*rewards)))),
    }


def write_logs(path: Path, work: Path) -> None:
    """Every process's output, and each run's progress.csv and config.json, as a tarball."""
    with tarfile.open(path, "w:gz") as tar:
        for f in sorted(work.glob("*.log")):
            tar.add(f, arcname=f.name)
        for name in ("single", "multi"):
            for f in ("progress.csv", "config.json"):
                if (work / name / f).exists():
                    tar.add(work / name / f, arcname=f"{name}/{f}")
        info = tarfile.TarInfo("README")
        text = b"Outputs of benchmarks/multiprocess.py (see multiprocess.json).\n"
        info.size = len(text)
        tar.addfile(info, io.BytesIO(text))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="folder for the JSON, markdown, logs")
    parser.add_argument("--env", default="MARA")
    parser.add_argument("--num_envs", type=int, default=4096, help="global (2048 per GPU)")
    parser.add_argument("--num_steps", type=int, default=32)
    parser.add_argument("--num_minibatches", type=int, default=0, help="0: the preset's")
    parser.add_argument("--updates", type=int, default=200)
    parser.add_argument("--updates_per_call", type=int, default=20)
    parser.add_argument("--platform", choices=("gpu", "cpu"), default="gpu")
    parser.add_argument("--order", nargs="+", default=["single", "multi"],
                        choices=("single", "multi"), help="layouts in the order run")  # fmt: skip
    parser.add_argument("--timeout", type=float, default=300, help="seconds per layout")
    parser.add_argument("extra", nargs="*", help="more train flags (after --)")
    args = parser.parse_args(argv)
    if set(args.order) != {"single", "multi"}:
        parser.error("--order must name both single and multi")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    common = train_flags(args)
    with tempfile.TemporaryDirectory(prefix="multiprocess-") as tmp:
        work = Path(tmp)
        try:
            report = compare(args, work, common)
        finally:  # the logs come back even when a layout failed
            write_logs(out / "logs.tar.gz", work)
        (out / "multiprocess.json").write_text(json.dumps(report, indent=2) + "\n")
        (out / "multiprocess.md").write_text(markdown(report))
    print(markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
