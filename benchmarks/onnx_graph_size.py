"""The ONNX graphs of the IK presets with deployed rules, as the suite exports them: graph
nodes, export + self-check time and one onnxruntime call (one thread, batch 1, median of
200 random observations), for `orient_first` (MARAOrient, with its 5-mm collision guard)
and `ik_finish` (MARA). Random weights of the suite's small network
(tests/test_export_plots.make_run), written under --out (a new folder).

    JAX_DEFAULT_MATMUL_PRECISION=highest python benchmarks/onnx_graph_size.py --out DIR

(The CLIs set that precision themselves; without it the export's self-check can miss its
1e-4 rad tolerance on a few observations.)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    if args.out.exists():
        print(f"error: {args.out} exists; name a new folder", file=sys.stderr)
        return 2
    import onnx
    import onnxruntime as ort
    from test_export_plots import make_run
    from test_onnx_graph import ORIENT_FIRST

    from mara_mjx.cli.export import export_policy

    presets = (
        ("orient_first", "MARAOrient", ORIENT_FIRST),
        ("ik_finish", "MARA", {"ik_finish": 0.06}),
    )
    for name, env, rules in presets:
        make_run(args.out / name, env, True, relative=True, **rules)
        start = time.perf_counter()
        path = export_policy(args.out / name, args.out / f"{name}.onnx", batch=1)
        export_s = time.perf_counter() - start
        options = ort.SessionOptions()
        options.intra_op_num_threads = options.inter_op_num_threads = 1
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        feed = session.get_inputs()[0]
        rng = np.random.default_rng(0)
        times = []
        for _ in range(200):
            obs = (0.1 * rng.normal(size=(1, feed.shape[-1]))).astype(np.float32)
            t = time.perf_counter()
            session.run(None, {feed.name: obs})
            times.append(time.perf_counter() - t)
        nodes = len(onnx.load(str(path)).graph.node)
        median_ms = 1000 * np.median(times)
        print(f"{name} ({env}): {nodes} graph nodes, export + check {export_s:.0f} s, "
              f"onnxruntime median {median_ms:.1f} ms")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
