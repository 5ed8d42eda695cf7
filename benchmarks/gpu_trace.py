"""Kernel-level summary of a `jax.profiler.trace` folder (a GPU profiling aid).

    from gpu_trace import traced, summarise
    with traced(DIR):
        jax.block_until_ready(fn(*args))
    print(summarise(DIR, top=15))

`summarise` reads the newest `*.trace.json.gz` under DIR/plugins/profile (the Chrome-trace
export that jax's profiler writes beside its xplane) and, for the device's stream lines
(threads named "Stream ..." of processes named "/device:GPU:N"), sums the kernels: how
many, their total time (the device busy time), the time from the first kernel's start to
the last one's end (the span; span - busy is where the device waited: launches, host
work, synchronisation), and the kernels taking the most time, grouped by name (with the
XLA op that launched them where the trace says). No tensorboard needed.

    python benchmarks/gpu_trace.py DIR [--top 15]
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import gzip
import json
from pathlib import Path


@contextlib.contextmanager
def traced(log_dir: str | Path):
    import jax

    jax.profiler.start_trace(str(log_dir))
    try:
        yield
    finally:
        jax.profiler.stop_trace()


def newest_trace(log_dir: str | Path) -> Path:
    files = Path(log_dir).glob("plugins/profile/*/*.trace.json.gz")
    files = sorted(files, key=lambda p: p.stat().st_mtime)
    if not files:
        raise FileNotFoundError(f"no *.trace.json.gz under {log_dir}/plugins/profile")
    return files[-1]


def summarise(log_dir: str | Path, top: int = 15) -> dict:
    with gzip.open(newest_trace(log_dir), "rt") as f:
        trace = json.load(f)
    events = trace["traceEvents"] if isinstance(trace, dict) else trace
    procs, threads = {}, {}
    for e in events:
        if e.get("ph") == "M" and e.get("name") == "process_name":
            procs[e["pid"]] = e.get("args", {}).get("name", "")
        if e.get("ph") == "M" and e.get("name") == "thread_name":
            threads[(e["pid"], e["tid"])] = e.get("args", {}).get("name", "")
    lines = collections.Counter()
    device = []
    for e in events:
        if e.get("ph") != "X" or "/device:GPU" not in procs.get(e.get("pid"), ""):
            continue
        thread = threads.get((e["pid"], e.get("tid")), "")
        lines[thread] += 1
        device.append((thread, e))
    streams = [t for t in lines if t.startswith("Stream")] or lines.most_common(1)[:1]
    streams = [t if isinstance(t, str) else t[0] for t in streams]
    kernels = [e for t, e in device if t in streams]
    if not kernels:
        return {"kernels": 0, "device_lines": dict(lines), "processes": sorted(set(procs.values()))}
    busy = sum(float(e.get("dur", 0)) for e in kernels)
    start = min(float(e["ts"]) for e in kernels)
    end = max(float(e["ts"]) + float(e.get("dur", 0)) for e in kernels)
    by_name: dict[str, list[float]] = collections.defaultdict(list)
    ops: dict[str, str] = {}
    for e in kernels:
        by_name[e["name"]].append(float(e.get("dur", 0)))
        args = e.get("args", {})
        op = args.get("hlo_op") or args.get("tf_op") or ""
        if op:
            ops.setdefault(e["name"], op)
    ranked = sorted(by_name.items(), key=lambda kv: -sum(kv[1]))
    return {
        "kernels": len(kernels),
        "busy_us": busy,
        "span_us": end - start,
        "device_lines": dict(lines),
        "top": [
            {
                "name": name[:120],
                "hlo_op": ops.get(name, ""),
                "count": len(d),
                "total_us": sum(d),
                "share": sum(d) / busy,
                "mean_us": sum(d) / len(d),
            }  # fmt: skip
            for name, d in ranked[:top]
        ],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("log_dir")
    p.add_argument("--top", type=int, default=15)
    args = p.parse_args()
    print(json.dumps(summarise(args.log_dir, args.top), indent=1))


if __name__ == "__main__":
    main()
