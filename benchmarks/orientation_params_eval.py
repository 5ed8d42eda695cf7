"""Evaluate saved fixed-target policies again, from the params a study pickled.

The per-seed params that `orientation_study.py --save-params DIR` pickles, with the
paper's evaluation (10 episodes, stop at the first step with every axis within 5 mm) and
the hold (the same episodes run to the horizon), as the saved policy runs (training-only
parts of the config off), or with `--training` as the trainer's network ran (e.g. with
train_ik_gate_roll's gate rule on), and with PPOConfig fields changed by `--set`.

    python benchmarks/orientation_params_eval.py DIR/MARAOrient_... --task MARAOrient \
        --seeds 0 1 2 3 4 [--training --set 'train_ik_gate_roll=true'] --out eval.json

Runs on the CPU (about a minute per seed on 2 cores); the evaluation is deterministic.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import struct

import mara_mjx
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import make_evaluate
from mara_mjx.ppo.networks import forward, make_network

sys.path.insert(0, os.path.dirname(__file__))
from orientation_study import parse_variant, seed_row  # noqa: E402
from random_target_study import load_saved_policy  # noqa: E402


@struct.dataclass
class TrainerPolicy:
    """A saved policy's params run through the trainer's network (make_network(...,
    training=True)): the deterministic mean as training itself saw it."""

    params: Any
    obs_stats: Any
    config: Any = struct.field(pytree_node=False)
    action_size: int = struct.field(pytree_node=False)

    def __call__(self, obs: jax.Array) -> jax.Array:
        network = make_network(self.config, self.action_size, training=True)
        return forward(network, self.params, self.obs_stats, obs, self.config.ppo.obs_clip)[0]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path, help="a --save-params folder of one (task, variant)")
    p.add_argument("--task", required=True)
    p.add_argument("--seeds", nargs="+", type=int, default=[0])
    p.add_argument("--set", default="", help="PPOConfig fields changed at inference: 'a=1;b=x'")
    p.add_argument("--training", action="store_true", help="run the trainer's network")
    p.add_argument("--eval-seed", type=int, default=0, help="EvalConfig.seed: the reset keys")
    p.add_argument("--out", default="")
    args = p.parse_args(argv)
    overrides = parse_variant(args.set) if args.set else {}
    env = mara_mjx.make(args.task)
    stop = jax.jit(make_evaluate(env, EvalConfig(seed=args.eval_seed)))
    hold = jax.jit(make_evaluate(env, EvalConfig(tolerance_mm=0.0, seed=args.eval_seed)))
    rows = []
    for seed in args.seeds:
        policy = load_saved_policy(args.folder, seed, overrides)
        if args.training:
            policy = TrainerPolicy(
                policy.params, policy.obs_stats, policy.config, policy.action_size
            )
        s, h = jax.device_get(stop(policy)), jax.device_get(hold(policy))
        row = {"seed": seed, **seed_row(s, h)}
        rows.append(row)
        print(
            f"{args.task} seed {seed}: reached {row['reached']}/10, "
            f"pos {np.round(row['position_mm'], 2).tolist()} mm, "
            f"ori {np.round(row['orientation_deg'], 2).tolist()} deg, "
            f"hold ori {np.round(row['hold_orientation_deg'], 2).tolist()}",
            flush=True,
        )
        if args.out:
            with open(args.out, "w") as f:
                json.dump(
                    {
                        "command": "python benchmarks/orientation_params_eval.py "
                        + shlex.join(sys.argv[1:] if argv is None else argv),
                        "device": str(jax.devices()[0]),
                        "jax": jax.__version__,
                        "folder": str(args.folder),
                        "task": args.task,
                        "set": overrides,
                        "training": args.training,
                        "eval_seed": args.eval_seed,
                        "per_seed": rows,
                    },
                    f,
                    indent=1,
                )


if __name__ == "__main__":
    main()
