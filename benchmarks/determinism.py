"""Which ops of the PPO update need `--xla_gpu_deterministic_ops`, and what the flag costs.

    python benchmarks/determinism.py --out $OUT/determinism        # on a GPU, ~3-4 min

Runs the default preset's PPO (the program of `python -m mara_mjx.train --env
MARACollisionOrient --preset default`: 2048 envs x 32 steps, `make_train`) in fresh processes under
several XLA_FLAGS settings (`--settings`, default nondet, noautotune, det; see SETTINGS).
Each process compiles `trainer.run`, runs `--calls` calls of `--updates` updates from
seed 0 (the first call also compiles), timing the later ones (env steps/s), hashes the
parameters' bits (sha256) after every call, then starts again from seed 0 in the same
process with the same executable and hashes again. So:

* a same-process repeat differs: the executable itself is non-deterministic (atomics:
  float scatter-adds, select-and-scatter, some GEMM / convolution algorithms);
* a second cold process (`cold2`) differs while each process repeats itself:
  compilation differs between processes (autotuning picked other kernels); `noautotune`
  (`--xla_gpu_autotune_level=0`) tests that, `warm` (a process loading `cold`'s
  executable from the persistent compilation cache) shows whether a cached executable
  reproduces.

The static side (on the CPU, tests/test_determinism.py): the lowered PPO update and env
step hold no float scatter-add or select-and-scatter. The optimized HLO of each
setting's `trainer.run` is written to OUT/hlo-<setting>.txt.gz, and OUT/ops-<setting>.json
counts the ops whose GPU implementation may be non-deterministic (scatter,
select-and-scatter, sort, reductions, cuBLAS / cuBLASLt / Triton GEMMs, cuDNN calls,
all-reduce), with their first lines. Results: OUT/determinism.json and a line per
process on stdout. On a CPU it runs too (`--num_envs 8 --num_steps 4 --updates 2` for a
smoke test), but the CPU backend is deterministic: it shows only that the script works.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SETTINGS = {  # name -> XLA_FLAGS added to the process's own
    "det": "--xla_gpu_deterministic_ops=true",
    "nondet": "--xla_gpu_deterministic_ops=false",
    # no autotuning: the same kernels in every compile (is the run-to-run difference
    # autotuning's choice, and what does the flag's cost come from?)
    "noautotune": "--xla_gpu_deterministic_ops=false --xla_gpu_autotune_level=0",
    # deterministic implementations of non-deterministic ops, autotuning kept
    "excl": "--xla_gpu_deterministic_ops=false --xla_gpu_exclude_nondeterministic_ops=true",
}
RUNS = ("cold", "cold2", "warm")
PATTERNS = {
    "scatter": r"\bscatter\(",
    "select-and-scatter": r"\bselect-and-scatter\(",
    "sort": r"\bsort\(",
    "reduce": r"\breduce\(",
    "reduce-window": r"\breduce-window\(",
    "all-reduce": r"\ball-reduce(-start)?\(",
    "cublas gemm": r"__cublas\$gemm",
    "cublasLt matmul": r"__cublas\$lt\$matmul",
    "triton gemm": r"__triton_gemm|\"kind\":\"__triton",
    "cudnn": r"__cudnn\$",
    "custom-call": r"\bcustom-call\(",
}


def child(args: argparse.Namespace) -> None:
    """One process: XLA_FLAGS from --setting, train, hash, repeat, print one JSON line."""
    flags = os.environ.get("XLA_FLAGS", "")
    for name in ("deterministic_ops", "autotune_level", "exclude_nondeterministic_ops"):
        flags = re.sub(rf"--xla_gpu_{name}=\S+", "", flags)
    os.environ["XLA_FLAGS"] = f"{flags} {SETTINGS[args.setting]}"
    import hashlib

    import jax
    import numpy as np

    from mara_mjx.cli.common import configure_jax

    configure_jax(args.cache)
    import mara_mjx
    from mara_mjx.ppo.presets import PRESETS
    from mara_mjx.ppo.train import make_train

    sizes = {k: v for k, v in (("num_envs", args.num_envs), ("num_steps", args.num_steps)) if v}
    config = PRESETS["default"].replace(**sizes)
    env = mara_mjx.make(args.env)
    trainer = make_train(env, config, updates_per_call=args.updates, devices=1)

    def digest(tree) -> str:
        h = hashlib.sha256()
        for leaf in jax.tree.leaves(jax.device_get(tree)):
            h.update(np.ascontiguousarray(leaf).tobytes())
        return h.hexdigest()[:16]

    def train() -> tuple[list[str], list[float]]:
        state = trainer.init(jax.random.key(0))
        hashes, seconds = [], []
        for _ in range(args.calls):
            start = time.monotonic()
            state, metrics = trainer.run(state, args.updates)
            jax.block_until_ready((state, metrics))
            seconds.append(time.monotonic() - start)
            hashes.append(digest(state.params))
        return hashes, seconds

    start = time.monotonic()
    hashes, seconds = train()
    first_s = time.monotonic() - start
    repeat, seconds2 = train()
    steady = sorted(seconds[1:] + seconds2[1:]) or [float("nan")]
    out = Path(args.out)
    hlo_path = out / f"hlo-{args.setting}.txt.gz"
    ops = None
    if not hlo_path.exists():
        state = trainer.init(jax.random.key(0))
        text = trainer.run.lower(state, args.updates).compile().as_text()
        with gzip.open(hlo_path, "wt") as f:
            f.write(text)
        ops = count_ops(text)
        (out / f"ops-{args.setting}.json").write_text(json.dumps(ops, indent=1))
    result = {
        "setting": args.setting,
        "run": args.run,
        "XLA_FLAGS": os.environ["XLA_FLAGS"].strip(),
        "device": str(jax.devices()[0].device_kind),
        "num_envs": config.ppo.num_envs,
        "num_steps": config.ppo.num_steps,
        "updates_per_call": args.updates,
        "hashes": hashes,
        "repeat_hashes": repeat,
        "same_process_identical": hashes == repeat,
        "first_call_s": round(first_s, 2),
        "env_steps_per_s": config.ppo.batch_size * args.updates / steady[len(steady) // 2],
        "op_counts": None if ops is None else {k: v["count"] for k, v in ops.items()},
    }
    print("RESULT " + json.dumps(result), flush=True)


def count_ops(text: str) -> dict:
    """{kind: {count, lines (the first 20)}} of the ops in PATTERNS in an HLO text."""
    found = {}
    lines = text.splitlines()
    for kind, pattern in PATTERNS.items():
        hits = [ln.strip()[:300] for ln in lines if re.search(pattern, ln)]
        found[kind] = {"count": len(hits), "lines": hits[:20]}
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="runs/determinism")
    parser.add_argument("--env", default="MARACollisionOrient")
    parser.add_argument(
        "--settings", nargs="+", default=["nondet", "noautotune", "det"], choices=SETTINGS
    )
    parser.add_argument("--runs", nargs="+", default=["cold", "cold2"], choices=RUNS)
    parser.add_argument("--updates", type=int, default=10, help="updates per call")
    parser.add_argument("--calls", type=int, default=3)
    parser.add_argument("--num_envs", type=int, default=0, help="0: the default preset's")
    parser.add_argument("--num_steps", type=int, default=0, help="0: the default preset's")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--setting", default="det", help=argparse.SUPPRESS)
    parser.add_argument("--run", default="cold", help=argparse.SUPPRESS)
    parser.add_argument("--cache", default="false", help=argparse.SUPPRESS)
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.child:
        child(args)
        return
    caches = Path(tempfile.mkdtemp(prefix="determinism-cache-"))
    results = []
    for setting in args.settings:
        for run in args.runs:
            cache = caches / f"{setting}-{'cold' if run == 'warm' else run}"
            cmd = [sys.executable, __file__, "--child", "--setting", setting, "--run", run]
            cmd += ["--cache", str(cache), "--out", str(out), "--env", args.env]
            cmd += ["--updates", str(args.updates), "--calls", str(args.calls)]
            cmd += ["--num_envs", str(args.num_envs), "--num_steps", str(args.num_steps)]
            start = time.monotonic()
            proc = subprocess.run(cmd, capture_output=True, text=True)
            lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
            if proc.returncode != 0 or not lines:
                print(f"{setting} {run}: failed\n{proc.stderr[-3000:]}", flush=True)
                continue
            result = json.loads(lines[-1][len("RESULT ") :])
            result["process_s"] = round(time.monotonic() - start, 1)
            results.append(result)
            print(
                f"{setting:7s} {run:6s} hashes {result['hashes']} same-process repeat "
                f"{'identical' if result['same_process_identical'] else 'DIFFERS'}, "
                f"{result['env_steps_per_s'] / 1e6:.2f} M env steps/s, first call "
                f"{result['first_call_s']} s, process {result['process_s']} s",
                flush=True,
            )
            (out / "determinism.json").write_text(json.dumps(results, indent=1))
    for setting in args.settings:
        rs = [r for r in results if r["setting"] == setting]
        finals = {r["run"]: r["hashes"][-1] for r in rs}
        print(
            f"{setting}: final params hash per run {finals}: "
            f"{'all identical' if len(set(finals.values())) == 1 else 'DIFFER'}"
        )
    print(f"wrote {out / 'determinism.json'} and the HLO of each setting")


if __name__ == "__main__":
    main()
