"""Where multi-device PPO time goes: rollout vs SGD, per device count (GPU profiling aid).

For each device count n, the default preset at weak scaling (--per-device-envs, default
2048, x 32 steps per device) is timed with update_epochs = 1 and 4. One epoch of SGD costs
(t(4) - t(1)) / 3 and the rest of an update (rollout, GAE, statistics) t(1) - that, so
their scaling efficiencies can be read apart:

    python benchmarks/scaling_phases.py --device-counts 1 2 4 --out phases.json

Times are per update: median of --repeats calls of --updates updates after a compile
call. Runs whichever mara_mjx is on the path (so a checkout of an older version can be
measured in the same session).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import jax

import mara_mjx
from mara_mjx.bench.runner import device_info, versions
from mara_mjx.ppo import PRESETS, make_train


def time_update(task: str, config, devices: int, updates: int, repeats: int) -> float:
    trainer = make_train(mara_mjx.make(task), config, updates_per_call=updates, devices=devices)
    state = trainer.init(jax.random.key(0))
    state, m = trainer.run(state, updates)  # compile
    jax.block_until_ready(m)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state, m = trainer.run(state, updates)
        jax.block_until_ready(m)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) / updates


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--device-counts", type=int, nargs="+", default=[1, 2])
    p.add_argument("--per-device-envs", type=int, default=2048)
    p.add_argument("--updates", type=int, default=10)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument(
        "--no-split", action="store_true", help="time the 4-epoch update only (no phases)"
    )
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    default = PRESETS["default"]
    rows = []
    for n in args.device_counts:
        t = {}
        for epochs in (4,) if args.no_split else (1, 4):
            config = default.replace(num_envs=args.per_device_envs * n, update_epochs=epochs)
            t[epochs] = time_update(args.task, config, n, args.updates, args.repeats)
        t.setdefault(1, float("nan"))
        sgd_epoch = (t[4] - t[1]) / 3
        row = {
            "devices": n,
            "update_s": t[4],
            "update_1_epoch_s": t[1],
            "sgd_epoch_s": sgd_epoch,
            "sgd_step_s": sgd_epoch / default.num_minibatches,
            "rest_s": t[1] - sgd_epoch,
            "env_steps_per_s": args.per_device_envs * default.num_steps * n / t[4],
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
    one = rows[0] if rows[0]["devices"] == 1 else None
    for r in rows:  # weak scaling: ideal is the same time per update
        for k in ("update_s", "sgd_epoch_s", "rest_s"):
            r[f"{k.removesuffix('_s')}_efficiency"] = one[k] / r[k] if one else None
    record = {
        "command": "python benchmarks/scaling_phases.py "
        + " ".join(
            f"--{k.replace('_', '-')} {' '.join(map(str, v)) if isinstance(v, list) else v}"
            for k, v in vars(args).items()
            if k not in ("out", "no_split")
        )
        + (" --no-split" if args.no_split else ""),
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
        "mara_mjx": str(Path(mara_mjx.__file__).parent),
        "device": device_info(),
        "versions": versions(),
        "config": default.to_dict(),
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
