"""Why settled Orient policies keep 1-5 deg of pitch: the reward landscape around them (issue 11).

CPU only. Reads a study JSON of `benchmarks/orientation_study.py` (the 'default' variant of
a task), takes each seed's settled configuration q* (the deterministic probe's final joint
positions), and compares it with the best reachable pose of the same arm branch (q_opt:
Gauss-Newton on the 6-D pose error over the joints that are not pinned at a limit, from
q*): the reward at both without noise, and the reward averaged over isotropic joint-space
Gaussian noise of several sizes (what PPO maximises with its joint-space exploration),
under the env's reward and under the default preset's training reward (beta 0.5, gamma
0.02). Kinematics: mara_mjx.envs.chain (checked against MJX in tests/test_chain.py).

    python benchmarks/archive/orientation_landscape.py \
        benchmarks/results/orientation/study10b_task_actions_and_default.json \
        --task MARACollisionOrient --out benchmarks/results/orientation/landscape.md
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np

import mara_mjx
from mara_mjx import rewards
from mara_mjx.envs.chain import Chain
from mara_mjx.envs.geometry import quat_canonical, quat_conj, quat_mul


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("study")
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--variant", default="default")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    p.add_argument("--sigmas", type=float, nargs="+", default=[0.01, 0.003, 0.001, 0.0003])
    p.add_argument("--samples", type=int, default=40000)
    p.add_argument("--out", default="")
    args = p.parse_args()

    env = mara_mjx.make(args.task)
    params = env.default_params
    chain = Chain.from_model(env.arm.mj_model)
    lower, upper = jnp.asarray(env.joint_lower), jnp.asarray(env.joint_upper)

    def pose_error(q):
        pos, quat = chain.tcp(q)
        quat_err = quat_canonical(quat_mul(quat, quat_conj(params.target_quat)))
        return pos - params.target_pos, quat_err

    def make_reward(beta, gamma):
        rp = params.reward

        def reward(q):
            e, quat_err = pose_error(q)
            d = rewards.rms_distance(e)
            theta = rewards.orientation_angle(quat_err)
            return (
                rewards.distance_term(d, rp.alpha, rp.done)
                * rewards.orientation_factor(theta, beta, gamma)
                - 1.0
            )

        return jax.jit(jax.vmap(reward))

    env_reward = make_reward(float(params.reward.beta), float(params.reward.gamma))
    train_reward = make_reward(0.5, 0.02)

    @jax.jit
    def best_in_branch(q):
        """Gauss-Newton on the pose error over the joints not pinned at a limit."""
        free = ((q > lower + 1e-3) & (q < upper - 1e-3)).astype(jnp.float32)
        q = jnp.clip(q, lower, upper)

        def body(q, _):
            e, quat_err = pose_error(q)
            residual = jnp.concatenate([e, 2.0 * quat_err[1:] * 0.1])
            jac = chain.jacobian(q) * jnp.array([1, 1, 1, 0.1, 0.1, 0.1])[:, None] * free
            dq = -jnp.linalg.lstsq(jac, residual)[0]
            return jnp.clip(q + 0.5 * dq, lower, upper), None

        return jax.lax.scan(body, q, None, 300)[0]

    def angle_deg(q):
        _, quat_err = pose_error(q)
        return float(np.degrees(2 * np.arccos(min(1.0, abs(float(quat_err[0]))))))

    study = json.load(open(args.study))
    run = next(
        r for r in study["results"] if r["task"] == args.task and r["variant"] == args.variant
    )
    last = run["timeline"][-1]
    lines = [
        f"# Reward landscape around the settled {args.task} policies ({args.variant} preset)",
        "",
        f"Command: `python benchmarks/archive/orientation_landscape.py {args.study} "
        f"--task {args.task}`",
        f"(settled configurations from `{run.get('variant')}` in {args.study}, "
        f"{args.samples} noise samples per point, same samples at both points).",
        "",
        "| seed | q* pitch/total error (deg) | joint distance to q_opt (rad) "
        "| q_opt error (mm, deg) | noise sigma (rad) | env reward: q* / q_opt "
        "| training reward: q* / q_opt |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in args.seeds:
        q_star = jnp.asarray(last["q_final"][s], jnp.float32)
        q_opt = best_in_branch(q_star)
        e_opt, _ = pose_error(q_opt)
        for i, sigma in enumerate([0.0, *args.sigmas]):
            noise = np.random.default_rng(1).normal(size=(args.samples, 6)) * sigma
            pts = lambda q: jnp.clip(q[None] + noise, lower, upper).astype(jnp.float32)  # noqa: E731
            env_pair = [float(env_reward(pts(q)).mean()) for q in (q_star, q_opt)]
            train_pair = [float(train_reward(pts(q)).mean()) for q in (q_star, q_opt)]
            head = (
                f"| {s} | {last['orientation_deg'][s][1]:.2f} / {angle_deg(q_star):.2f} "
                f"| {', '.join(f'{x:+.3f}' for x in np.asarray(q_opt - q_star))} "
                f"| {1000 * float(jnp.max(jnp.abs(e_opt))):.3f}, {angle_deg(q_opt):.2f} "
                if i == 0
                else "| | | | "
            )
            lines.append(
                head + f"| {sigma:g} | {env_pair[0]:.3f} / {env_pair[1]:.3f} "
                f"| {train_pair[0]:.3f} / {train_pair[1]:.3f} |"
            )
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text)


if __name__ == "__main__":
    main()
