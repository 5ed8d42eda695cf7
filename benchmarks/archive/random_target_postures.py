"""Where random-target policies settle: joint-limit saturation and orientation error
(issue 12, benchmarks/NOTES.md section 23).

Loads the per-seed params that `random_target_study.py --save-params DIR` pickles
((params, obs_stats, config dict) per seed), rolls each deterministic policy out from the
reset pose to `--poses` held-out poses (evaluation stream, seed 7) for `--steps` steps on
the train driver, and prints per seed: the median final distance, the mean orientation
error per axis, the fraction of poses with any axis over 10 deg, and per joint the
fraction of final poses within 0.02 rad of a limit (all poses, those over 10 deg, the
rest), with the mean and spread of the final joints.

    python benchmarks/archive/random_target_postures.py \
        DIR/MARACollisionOrientRandomTarget_default --seeds 0 1 2 3 4 [--ik-finish 100] \
        [--set 'ik_gate=0.1']
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import jax
import numpy as np

import mara_mjx
from mara_mjx.envs import targets
from mara_mjx.envs.task_space import pose_step
from mara_mjx.ppo import target_eval

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # benchmarks/
from orientation_study import parse_variant  # noqa: E402
from random_target_study import load_saved_policy  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path, help="a --save-params folder of one (task, variant)")
    p.add_argument("--task", default="MARACollisionOrientRandomTarget")
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    p.add_argument("--poses", type=int, default=200)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument(
        "--ik-finish",
        type=int,
        default=0,
        help="then this many steps of the bare IK step (task_space.pose_step) from where "
        "the policy left the arm: how far the near-goal error is the policy's, not the "
        "branch's",
    )
    p.add_argument(
        "--wrap", action="store_true", help="the finishing IK step with wrap_last (pose_step)"
    )
    p.add_argument(
        "--set",
        default="",
        help="'key=value;...' PPOConfig overrides applied at inference (JSON values), e.g. "
        "'ik_gate=0.1': a policy run with settings other than those it was trained with",
    )
    args = p.parse_args(argv)

    env = mara_mjx.make(args.task)
    poses = targets.evaluation_poses(env.arm.mj_model, env.region, args.poses, 7)
    params = target_eval.with_targets(env.make_params(reset_noise=0.0), poses.pos, poses.quat)
    lo, hi = np.asarray(env.joint_lower), np.asarray(env.joint_upper)
    keys = jax.random.split(jax.random.key(0), args.poses)
    qi = next(p["start"] for p in env.observation_layout if p["name"] == "quat_err")
    for seed in args.seeds:
        policy = load_saved_policy(args.folder, seed, parse_variant(args.set) if args.set else {})

        @jax.jit
        def rollout(keys, params, policy=policy):
            def one(key, prm):
                def body(st, _):
                    return env.step(st, policy(st.obs)), None

                def ik(st, _):
                    o = st.obs
                    return env.step(
                        st, o[:6] + pose_step(o[:6], o[6:9], o[qi : qi + 4], args.wrap)
                    ), None

                st, _ = jax.lax.scan(body, env.reset(key, prm), None, length=args.steps)
                if args.ik_finish:
                    st, _ = jax.lax.scan(ik, st, None, length=args.ik_finish)
                return st.obs, st.metrics["orientation_error"], st.metrics["distance"]

            return jax.vmap(one)(keys, params)

        obs, ori, dist = jax.device_get(rollout(keys, params))
        q, ori = obs[:, :6], np.degrees(ori)
        at = (np.abs(q - lo) < 0.02) | (np.abs(q - hi) < 0.02)
        bad = ori.max(1) > 10

        def frac(mask):
            return at[mask].mean(0).round(2).tolist() if mask.any() else None

        print(
            f"seed {seed}: distance median {np.median(dist) * 1000:.2f} mm, orientation mean "
            f"{ori.mean(0).round(1).tolist()} deg, any axis > 10 deg {bad.mean():.2f}\n"
            f"  joint at a limit: all {frac(np.ones_like(bad))}, > 10 deg {frac(bad)}, "
            f"<= 10 deg {frac(~bad)}\n"
            f"  final q mean {q.mean(0).round(2).tolist()}, std {q.std(0).round(2).tolist()}",
            flush=True,
        )


if __name__ == "__main__":
    main()
