"""Random-target study: several seeds per (task, variant) in one program, held-out poses.

Which trainer-side recipe gives one policy that reaches any pose of the region. Several
seeds of each (task, variant) train in one vmapped program (ppo.members.make_seed_trainer,
as benchmarks/orientation_study.py); at the end every seed's policy is evaluated on
`--poses` held-out poses exactly as `python -m mara_mjx.evaluate` does for a random-target
run (ppo.target_eval: evaluation stream disjoint from the training table's, hold to the
horizon, per-axis mean / median / p95 / worst).

    python benchmarks/random_target_study.py --tasks MARACollisionOrientRandomTarget \
        --seeds 0 1 --variants default 'train_reward_until=1.0' \
        --total-timesteps 150000000 --out study.json

Variants: 'default' (the train CLI's preset for the task, `ppo.presets.default_preset`) or
'key=value;key=value' overrides of it (JSON values, as orientation_study.py); `--env`
'key=value;...' EnvConfig overrides (e.g. 'target_table_size=16384') apply to every
variant.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pickle
import sys
import time

import jax
import numpy as np

import mara_mjx
from mara_mjx.envs import targets
from mara_mjx.ppo import target_eval
from mara_mjx.ppo.config import TrainConfig
from mara_mjx.ppo.evaluation import evaluate, make_evaluate
from mara_mjx.ppo.members import make_seed_trainer, take_seed
from mara_mjx.ppo.policy import make_policy
from mara_mjx.ppo.presets import PRESETS, default_preset
from mara_mjx.ppo.train import make_train

sys.path.insert(0, os.path.dirname(__file__))
from orientation_study import parse_variant, run_studies, save_seed_params  # noqa: E402


def load_saved_policy(folder, seed: int, overrides: dict | None = None):
    """The deterministic policy of `seed` from a `--save-params` folder (what `study`
    pickles: params, obs_stats, config dict), with PPOConfig `overrides` if given."""
    with open(os.path.join(folder, f"seed{seed}.pkl"), "rb") as f:
        net_params, stats, cfg = pickle.load(f)
    cfg = {k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()}
    return make_policy(net_params, TrainConfig.from_dict(cfg).replace(**(overrides or {})), stats)


def study(task: str, variant: str, seeds: tuple[int, ...], args) -> dict:
    t0 = time.monotonic()
    env_overrides = parse_variant(args.env) if args.env else {}
    env = mara_mjx.make(task, **env_overrides)
    overrides = {} if variant == "default" else parse_variant(variant)
    sizes = {"num_envs": 16, "num_steps": 8, "num_minibatches": 4} if args.tiny else {}
    if args.total_timesteps:
        sizes["total_timesteps"] = args.total_timesteps
    config = PRESETS[default_preset(task)].replace(**{**sizes, **overrides})  # variant wins
    trainer = make_train(env, config, updates_per_call=args.chunk, devices=1)
    config = trainer.config
    st = make_seed_trainer(trainer, seeds)
    state = st.init()
    done, first, rows = 0, {}, []
    while done < trainer.num_updates:
        n = min(args.chunk, trainer.num_updates - done)
        state, metrics = st.run(state, n)
        metrics = jax.device_get(metrics)
        done += n
        now = time.monotonic() - t0
        det_err = np.asarray(metrics["det_error_mm"])[:, :n]  # (S, n)
        for thr in (5.0, 1.0):
            for i, s in enumerate(seeds):
                if (thr, s) not in first and np.nanmin(det_err[i]) < thr:
                    first[(thr, s)] = now
        rows.append(
            {
                "update": done,
                "time_s": now,
                "det_error_mm": det_err[:, -1].tolist(),
                **{
                    k: np.asarray(metrics[k])[:, n - 1].tolist()
                    for k in ("det_ori_err_x_deg", "det_ori_err_y_deg", "det_ori_err_z_deg")
                    if k in metrics
                },
            }
        )
    jax.block_until_ready(state)
    train_s = time.monotonic() - t0
    ev_config = target_eval.eval_config({"episodes": args.poses})
    poses = targets.evaluation_poses(
        env.arm.mj_model, env.region, ev_config.episodes, ev_config.seed
    )
    params = target_eval.with_targets(
        env.make_params(reset_noise=ev_config.noise), poses.pos, poses.quat
    )
    fn = make_evaluate(env, ev_config, params)
    if args.real_velocity:
        real_env = mara_mjx.make(task, driver="real", velocity=args.real_velocity, **env_overrides)
        real_params = target_eval.with_targets(
            real_env.make_params(reset_noise=ev_config.noise), poses.pos, poses.quat
        )
        real_config = dataclasses.replace(ev_config, rate_limit=args.real_rate_limit)
        real_fn = make_evaluate(real_env, real_config, real_params)
    per_seed = []
    for i, s in enumerate(seeds):
        seed_state = take_seed(state, i)
        policy = make_policy(seed_state, config)
        if args.save_params:  # for offline analysis: (params, obs_stats, config) per seed
            save_seed_params(args.save_params, task, variant, s, seed_state, config)
        res = evaluate(env, policy, ev_config, params, fn=fn)
        train = env.pose_table().pos
        gaps = np.linalg.norm(poses.pos[:, None, :] - train[None, :, :], axis=-1)
        tres = target_eval.TargetEvalResult(res, poses.pos, poses.quat, 1000 * gaps.min(1))
        summary = tres.summary(env.task.orientation)
        if args.real_velocity:  # the same policy and poses on the servo-driven real driver
            rres = evaluate(real_env, policy, real_config, real_params, fn=real_fn)
            rsum = target_eval.TargetEvalResult(
                rres, poses.pos, poses.quat, tres.nearest_training_mm
            ).summary(env.task.orientation)
            summary["real_driver"] = {
                "velocity": args.real_velocity,
                "rate_limit": args.real_rate_limit,
                **rsum,
            }
        summary["time_to_5mm_s"] = first.get((5.0, s))
        summary["time_to_1mm_s"] = first.get((1.0, s))
        per_seed.append({"seed": s, **summary})
    out = {
        "task": task,
        "variant": variant,
        "env_overrides": env_overrides,
        "config": config.to_dict(),
        "env_config": env.config.to_dict() if hasattr(env.config, "to_dict") else None,
        "seeds": list(seeds),
        "train_s": train_s,
        "env_steps_per_s": len(seeds) * trainer.num_updates * trainer.steps_per_update / train_s,
        "per_seed": per_seed,
        "timeline": rows,
    }
    print(f"== {task} {variant} (env {env_overrides}): train {train_s:.0f} s", flush=True)
    for r in per_seed:
        pos = r["position_error_mm"]
        line = (
            f"  seed {r['seed']}: pos mean {np.round(pos['mean'], 2).tolist()} p95 "
            f"{np.round(pos['p95'], 2).tolist()} mm, within 5/1 mm {r['within_mm']}"
        )
        if "orientation_error_deg" in r:
            ori = r["orientation_error_deg"]
            line += (
                f", ori mean {np.round(ori['mean'], 2).tolist()} median "
                f"{np.round(ori['median'], 2).tolist()} p95 {np.round(ori['p95'], 2).tolist()}"
            )
        line += f", collisions {r['collisions']} in {r['episodes_with_collisions']} episodes"
        print(line + f", 1 mm at {r['time_to_1mm_s']}", flush=True)
        if "real_driver" in r:
            rd = r["real_driver"]
            print(
                f"    real driver {rd['velocity']} rad/s: pos mean "
                f"{np.round(rd['position_error_mm']['mean'], 2).tolist()} mm, within 5/1 mm "
                f"{rd['within_mm']}, ori mean "
                f"{np.round(rd.get('orientation_error_deg', {}).get('mean', []), 2).tolist()}, "
                f"collisions in {rd['episodes_with_collisions']} episodes",
                flush=True,
            )
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tasks", nargs="+", default=["MARACollisionOrientRandomTarget"])
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    p.add_argument("--variants", nargs="+", default=["default"])
    p.add_argument("--env", default="", help="EnvConfig overrides 'key=value;...'")
    p.add_argument("--total-timesteps", type=int, default=0)
    p.add_argument("--chunk", type=int, default=50)
    p.add_argument("--poses", type=int, default=1000)
    p.add_argument("--tiny", action="store_true", help="CPU smoke test sizes")
    p.add_argument(
        "--real-velocity",
        type=float,
        default=0.0,
        help="also evaluate every policy on the real driver at this servo speed (rad/s)",
    )
    p.add_argument(
        "--real-rate-limit",
        action="store_true",
        help="the real-driver evaluation with EvalConfig.rate_limit (the policy's steps "
        "scaled to the servo speed, direction kept)",
    )
    p.add_argument("--out", default="random_target_study.json")
    p.add_argument(
        "--save-params",
        default="",
        help="folder: each seed's (params, obs_stats, config dict) pickled, for offline analysis",
    )
    args = p.parse_args()
    if args.real_rate_limit and not args.real_velocity:
        p.error("--real-rate-limit applies to the real-driver evaluation: add --real-velocity")
    run_studies(
        study, args, "random_target_study.py", mara_mjx=getattr(mara_mjx, "__version__", None)
    )


if __name__ == "__main__":
    main()
