"""Where one PPO update's time goes on the device: rollout vs SGD, kernel by kernel.

    python benchmarks/ppo_profile.py --task MARACollisionOrient [--preset orient_first] \
        [--set num_minibatches=8 ...] [--env-sizes 65536] --out profile.json

For the task's train CLI preset (or `--preset`) with `--set` overrides:

* `update`: seconds per update with the preset's update_epochs and with 1 epoch (median of
  `--repeats` calls of `--updates` updates, compile apart); one SGD epoch is the
  difference / (epochs - 1), the rest (rollout, GAE, statistics) what is left.
* `update_kernels`: one warm call under `jax.profiler.trace`, summarised per update by
  gpu_trace.summarise (kernel count, device busy time, span, the kernels taking most time).
* `--update-only`: only the first two (the preset's update_epochs).
* `env_step`: BatchedEnv.step (what the rollout calls) scanned over `--env-steps` steps
  with actions from a table, at the preset's num_envs and each `--env-sizes`: env steps/s
  and the kernel summary per step.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from gpu_trace import summarise, traced  # noqa: E402

import mara_mjx  # noqa: E402
from mara_mjx.bench.runner import device_info, versions  # noqa: E402
from mara_mjx.envs.batched import BatchedEnv  # noqa: E402
from mara_mjx.ppo import PRESETS, make_train  # noqa: E402
from mara_mjx.ppo.presets import default_preset  # noqa: E402


def per(summary: dict, n: int) -> dict:
    out = dict(summary)
    for k in ("kernels", "busy_us", "span_us"):
        if k in out:
            out[f"{k}_per"] = out[k] / n
    return out


def time_calls(fn, state, repeats: int):
    state = jax.block_until_ready(fn(state))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state = jax.block_until_ready(fn(state))
        times.append(time.perf_counter() - t0)
    return state, statistics.median(times)


def update_times(env, config, updates: int, repeats: int, trace_dir: Path | None) -> dict:
    trainer = make_train(env, config, updates_per_call=updates)
    state = trainer.init(jax.random.key(0))
    t0 = time.perf_counter()
    state = jax.block_until_ready(trainer.run(state, updates)[0])
    first = time.perf_counter() - t0
    state, call = time_calls(lambda s: trainer.run(s, updates)[0], state, repeats)
    row = {"first_call_s": first, "update_s": call / updates,
           "env_steps_per_s": config.ppo.batch_size * updates / call}  # fmt: skip
    if trace_dir is not None:
        with traced(trace_dir):
            jax.block_until_ready(trainer.run(state, updates)[0])
        row["kernels"] = per(summarise(trace_dir), updates)
    return row


def env_step(env, n: int, steps: int, repeats: int, trace_dir: Path) -> dict:
    benv = BatchedEnv(env, n, devices=1)
    lo, hi = np.asarray(env.joint_lower), np.asarray(env.joint_upper)
    table = jnp.asarray(np.random.default_rng(0).uniform(lo, hi, (8, n, 6)).astype(np.float32))

    @jax.jit
    def loop(state):
        def body(s, t):
            return benv.step(s, table[t % 8]), None

        return jax.lax.scan(body, state, jnp.arange(steps))[0]

    state = benv.reset(jax.random.key(0))
    state, call = time_calls(loop, state, repeats)
    with traced(trace_dir):
        jax.block_until_ready(loop(state))
    return {"envs": n, "env_steps_per_s": n * steps / call, "step_us": call / steps * 1e6,
            "kernels": per(summarise(trace_dir), steps)}  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--preset", default="")
    p.add_argument("--set", nargs="*", default=[], help="field=value overrides")
    p.add_argument("--updates", type=int, default=10)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--env-sizes", type=int, nargs="*", default=[65536])
    p.add_argument("--env-steps", type=int, default=50)
    p.add_argument(
        "--update-only", action="store_true", help="the full update's time alone (no split)"
    )
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    preset = args.preset or default_preset(args.task)
    overrides = {}
    for kv in args.set:
        k, v = kv.split("=", 1)
        overrides[k] = json.loads(v) if v[:1] in "0123456789-[{tf" else v
    config = PRESETS[preset].replace(**overrides)
    env = mara_mjx.make(args.task)
    tmp = Path(tempfile.mkdtemp(prefix="ppo_profile_"))
    record = {"command": "python " + " ".join(sys.argv), "preset": preset,
              "overrides": overrides, "device": device_info(), "versions": versions()}  # fmt: skip
    full = update_times(env, config, args.updates, args.repeats, tmp / "update")
    if args.update_only:
        record["update"] = full
        print(json.dumps({k: v for k, v in full.items() if k != "kernels"}), flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(record, indent=1))
        return
    one = update_times(env, config.replace(update_epochs=1), args.updates, args.repeats, None)
    epochs = config.update_epochs
    sgd_epoch = (full["update_s"] - one["update_s"]) / max(epochs - 1, 1)
    record["update"] = {"epochs": epochs, **full, "update_1_epoch_s": one["update_s"],
                        "sgd_epoch_s": sgd_epoch,
                        "sgd_step_s": sgd_epoch / config.num_minibatches,
                        "rest_s": one["update_s"] - sgd_epoch}  # fmt: skip
    print(json.dumps({k: v for k, v in record["update"].items() if k != "kernels"}), flush=True)
    record["env_step"] = []
    for n in dict.fromkeys([config.ppo.num_envs, *args.env_sizes]):
        row = env_step(env, n, args.env_steps, args.repeats, tmp / f"env_{n}")
        record["env_step"].append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "kernels"}), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
