"""Why held-out poses of a random-target seed were missed: their episodes, step by step.

The deployed policy of a checkpoint (its plan, restarts and guard, as `python -m
mara_mjx.evaluate` and the robustness study run it) on the named episodes of the
held-out poses (`ppo.target_eval`: evaluation seed `--eval_seed`, 1,000 poses, episode i
from reset key split(key(seed), 1000)[i], so episode i here is episode i there), all
stepped together for `--steps`. Per episode: its target, then one line per shown step:
|e| per axis (mm), the orientation error per axis (deg), the clearance to the nearest
contact (mm), whether the step collided, the largest joint move commanded and the joints.
A wrist held at a joint's stop shows a constant row with that joint at +-3.14.

    python benchmarks/target_trace.py RUN/seed_S --episodes 1 18 732 [--steps 64]

(benchmarks/NOTES.md section 68: study 68's seed 1629, joint 4 at its stop.)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np


def trace(run: Path, eval_seed: int, episodes: list[int], steps: int) -> dict[str, np.ndarray]:
    """Per step (steps, episodes, ...) arrays of the deployed policy's episodes."""
    from mara_mjx.envs import targets
    from mara_mjx.envs.clearance import clearance
    from mara_mjx.envs.random_target import with_targets
    from mara_mjx.ppo import checkpoint as ckpt
    from mara_mjx.ppo import policy as policy_io
    from mara_mjx.ppo.evaluation import deployed_policy
    from mara_mjx.ppo.target_eval import DEFAULTS
    from mara_mjx.runtime import runs

    arrays, meta = ckpt.load_checkpoint(ckpt.find_checkpoint(run))
    env = runs.make_env(meta)
    config = DEFAULTS.replace(seed=eval_seed)
    policy = deployed_policy(policy_io.policy_from_checkpoint(arrays, meta), config, env)
    poses = targets.evaluation_poses(env.arm.mj_model, env.region, config.episodes, eval_seed)
    params = with_targets(
        env.make_params(reset_noise=config.noise), poses.pos[episodes], poses.quat[episodes]
    )
    keys = jax.random.split(jax.random.key(eval_seed), config.episodes)[jnp.asarray(episodes)]
    n = env.action_size

    @jax.jit
    def run_all(keys, params):
        state = jax.vmap(env.reset)(keys, params)

        def body(state, _):
            action = policy(state.obs)
            nxt = jax.vmap(env.step)(state, action)
            row = {
                "e_mm": 1000.0 * nxt.metrics["position_error"],
                "o_deg": jnp.degrees(nxt.metrics["orientation_error"]),
                "clearance_mm": 1000.0 * clearance(nxt.obs[..., :n]),
                "collided": nxt.metrics["collided"],
                "move": jnp.max(jnp.abs(action - state.obs[..., :n]), -1),
                "q": nxt.obs[..., :n],
            }
            return nxt, row

        return jax.lax.scan(body, state, None, length=steps)[1]

    rows = {k: np.asarray(v) for k, v in run_all(keys, params).items()}
    rows["target_pos"], rows["target_quat"] = poses.pos[episodes], poses.quat[episodes]
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path)
    p.add_argument("--episodes", type=int, nargs="+", required=True)
    p.add_argument("--eval_seed", type=int, default=1000)
    p.add_argument("--steps", type=int, default=64)
    args = p.parse_args(argv)
    rows = trace(args.run, args.eval_seed, args.episodes, args.steps)
    shown = sorted({*range(min(6, args.steps)), *range(8, args.steps, max(1, args.steps // 8)),
                    args.steps - 1})  # fmt: skip
    for j, i in enumerate(args.episodes):
        print(f"episode {i}: target {np.round(rows['target_pos'][j], 3)} "
              f"quat {np.round(rows['target_quat'][j], 3)}; "
              f"collisions {int(rows['collided'][:, j].sum())}")  # fmt: skip
        print("  step | e x, y, z mm | roll, pitch, yaw deg | clearance mm | collided | move | q")
        for t in shown:
            e, o, hit = rows["e_mm"][t, j], rows["o_deg"][t, j], int(rows["collided"][t, j])
            print(f"  {t:4d} | {e[0]:8.2f} {e[1]:8.2f} {e[2]:8.2f} | {o[0]:6.1f} {o[1]:6.1f}"
                  f" {o[2]:6.1f} | {rows['clearance_mm'][t, j]:6.1f} | {hit}"
                  f" | {rows['move'][t, j]:.3f} | {np.round(rows['q'][t, j], 2)}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
