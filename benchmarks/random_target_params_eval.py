"""Evaluate saved random-target policies again on held-out poses, with any driver.

The per-seed params that `random_target_study.py --save-params DIR` pickles, on
`--poses` held-out poses exactly as the study's own evaluation (ppo.target_eval:
evaluation stream disjoint from the training table's, hold to the horizon).

    python benchmarks/random_target_params_eval.py \
        benchmarks/results/random_target/params/study27_mcort --seeds 0 1 \
        --driver real --velocity 0.3 --poses 100 [--rate-limit] --out real.json

Runs anywhere JAX does (the real driver is MJX physics; on a 2-core CPU 100 poses take
minutes per seed).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax

import mara_mjx
from mara_mjx.envs import targets
from mara_mjx.ppo import target_eval
from mara_mjx.ppo.evaluation import evaluate, make_evaluate

sys.path.insert(0, os.path.dirname(__file__))
from random_target_study import load_saved_policy  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path, help="a --save-params folder of one (task, variant)")
    p.add_argument("--task", default="MARACollisionOrientRandomTarget")
    p.add_argument("--seeds", nargs="+", type=int, default=[0])
    p.add_argument("--driver", default="train", choices=["train", "real"])
    p.add_argument("--velocity", type=float, default=0.3, help="rad/s, real driver only")
    p.add_argument("--poses", type=int, default=100)
    p.add_argument(
        "--rate-limit",
        action="store_true",
        help="EvalConfig.rate_limit (real driver: the policy's steps scaled to the servo "
        "speed, direction kept)",
    )
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    missing = [s for s in args.seeds if not (args.folder / f"seed{s}.pkl").is_file()]
    if missing:
        p.error(f"no seed{{{','.join(map(str, missing))}}}.pkl in {args.folder}")

    kw = {"driver": "real", "velocity": args.velocity} if args.driver == "real" else {}
    env = mara_mjx.make(args.task, **kw)
    ev_config = target_eval.eval_config({"episodes": args.poses, "rate_limit": args.rate_limit})
    poses = targets.evaluation_poses(
        env.arm.mj_model, env.region, ev_config.episodes, ev_config.seed
    )
    params = target_eval.with_targets(
        env.make_params(reset_noise=ev_config.noise), poses.pos, poses.quat
    )
    fn = make_evaluate(env, ev_config, params)
    train = env.pose_table().pos
    gaps = ((poses.pos[:, None, :] - train[None, :, :]) ** 2).sum(-1) ** 0.5
    command = "python benchmarks/random_target_params_eval.py " + " ".join(sys.argv[1:])
    out = []

    def write() -> None:  # after every seed: a cut-off run keeps what it measured
        args.out.write_text(
            json.dumps(
                {
                    "command": command,
                    "device": str(jax.devices()[0]),
                    "jax": jax.__version__,
                    "task": args.task,
                    "driver": args.driver,
                    "velocity": args.velocity if args.driver == "real" else None,
                    "rate_limit": args.rate_limit,
                    "folder": str(args.folder),
                    "results": out,
                }
            )
        )

    for seed in args.seeds:
        t0 = time.monotonic()
        policy = load_saved_policy(args.folder, seed)
        res = evaluate(env, policy, ev_config, params, fn=fn)
        summary = target_eval.TargetEvalResult(
            res, poses.pos, poses.quat, 1000 * gaps.min(1)
        ).summary(env.task.orientation)
        out.append({"seed": seed, "seconds": time.monotonic() - t0, **summary})
        o = summary.get("orientation_error_deg", {}).get("mean", [])
        print(
            f"seed {seed}: pos mean {[round(x, 2) for x in summary['position_error_mm']['mean']]}"
            f" mm, within 5/1 mm {summary['within_mm']}, ori mean {[round(x, 2) for x in o]}, "
            f"episodes with collisions {summary['episodes_with_collisions']}",
            flush=True,
        )
        write()


if __name__ == "__main__":
    main()
