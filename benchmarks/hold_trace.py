"""Does a trained policy stay at the target: per-step distance of its episode to the horizon.

The deterministic policy from the reset pose to the horizon, per-step RMS distance (mm)
printed for the first steps and the last steps.

    python benchmarks/hold_trace.py RUN_FOLDER [RUN_FOLDER ...] [--last 12]

A policy that reaches and stays shows a flat tail; a limit cycle shows a repeating
pattern. Also runs the paper's evaluation to the horizon (10 noisy episodes,
EvalConfig(tolerance_mm=0)). Writes <run>/hold_trace.json (every step's distance and
collision flag, and that evaluation's summary).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import numpy as np

from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo import policy as policy_io
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import evaluate
from mara_mjx.runtime import runs


def trace(run: Path) -> dict:
    arrays, meta = ckpt.load_checkpoint(ckpt.find_checkpoint(run))
    env = runs.make_env(meta)
    policy = policy_io.policy_from_checkpoint(arrays, meta)

    def body(state, _):
        state = env.step(state, policy(state.obs))
        return state, (state.metrics["distance"], state.metrics["collided"])

    @jax.jit
    def episode(key):
        state = env.reset(key)
        _, out = jax.lax.scan(body, state, None, length=env.max_episode_steps)
        return out

    distance, collided = jax.device_get(episode(jax.random.key(0)))
    horizon = evaluate(env, policy, EvalConfig(tolerance_mm=0.0)).summary()
    return {
        "distance_mm": (1000.0 * np.asarray(distance)).tolist(),
        "collided": np.asarray(collided).astype(int).tolist(),
        "eval_to_horizon": horizon,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--last", type=int, default=12)
    args = p.parse_args()
    for run in args.runs:
        out = trace(run)
        (run / "hold_trace.json").write_text(json.dumps(out))
        d = np.asarray(out["distance_mm"])
        first = " ".join(f"{x:.2f}" for x in d[:8])
        last = " ".join(f"{x:.2f}" for x in d[-args.last :])
        print(f"{run.name}: first steps {first}")
        print(f"{run.name}: last {args.last} steps {last}")
        print(
            f"{run.name}: mean distance over the last 512 steps {d[-512:].mean():.3f} mm, "
            f"collisions {int(np.sum(out['collided']))}"
        )
        h = out["eval_to_horizon"]
        pos = ", ".join(
            f"{m:.2f} +- {s:.2f}" for m, s in zip(*h["position_error_mm"].values(), strict=True)
        )
        ori = ", ".join(f"{m:.2f}" for m in h["orientation_error_deg"]["mean"])
        print(f"{run.name}: eval to the horizon (10 episodes): x, y, z mm {pos}; deg {ori}")


if __name__ == "__main__":
    main()
