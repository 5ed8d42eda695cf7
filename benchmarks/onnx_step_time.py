"""One arm's step through an exported .onnx policy, as a robot runs it: onnxruntime on one
thread, one observation per call, median and 95th percentile over N reset observations of
the task (targets far) and over the same postures at their target (e = 0, quat_err =
identity, at rest: where a planned policy's own landing reaches, so its restarts' loop
runs no group), and over the export's self-check observations (`onnx_graph.check_observations`:
random, spread over the rules' zones; a planned policy's own landing mostly misses there,
so the restarts run).

    python -m mara_mjx.export RUN/seed_S policy.onnx --batch 1 [--plan_starts 8]
    python benchmarks/onnx_step_time.py policy.onnx [--env NAME] [--calls 64]

--env: the task whose resets give the observations (default: the export's metadata).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("onnx")
    p.add_argument("--env", default="")
    p.add_argument("--calls", type=int, default=64)
    args = p.parse_args(argv)
    import jax
    import onnx
    import onnxruntime as ort

    import mara_mjx
    from mara_mjx.deploy import onnx_graph

    meta = json.loads({m.key: m.value for m in onnx.load(args.onnx).metadata_props}["mara_mjx"])
    env = mara_mjx.make(args.env or meta["env_name"])
    keys = jax.random.split(jax.random.key(3), args.calls)
    reset = np.asarray(jax.vmap(env.reset)(keys).obs, np.float32)
    at_target = reset.copy()
    at_target[:, 6:] = 0.0  # e = 0, v = 0 (and quat_err below)
    if reset.shape[1] == 16:
        at_target[:, 9] = 1.0  # quat_err = identity
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    options.log_severity_level = 3
    session = ort.InferenceSession(args.onnx, options, providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    print(f"{args.onnx}: one observation per call, onnxruntime {ort.__version__}, one thread")
    checks = np.asarray(onnx_graph.check_observations(meta, args.calls), np.float32)
    cases = (("reset observations", reset), ("at the target", at_target),
             ("self-check observations", checks))  # fmt: skip
    for label, obs in cases:
        times = []
        for row in obs:
            start = time.perf_counter()
            session.run(None, {name: row[None]})
            times.append(time.perf_counter() - start)
        ms = 1e3 * np.asarray(times[4:])  # (the first calls warm up)
        print(f"  {label}: median {np.median(ms):.3f} ms, p95 {np.percentile(ms, 95):.3f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
