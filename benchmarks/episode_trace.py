"""Why an episode of the paper's evaluation failed: its steps, one line each.

The deterministic policy of a checkpoint from the evaluation's own reset keys (EvalConfig:
`--eval_seed`, `--episodes`, the reset noise; the same episodes `python -m mara_mjx.evaluate`
and the robustness study run), all episodes stepped together to `--steps`. For every
episode that does not end within 5 mm (or that `--episode` names) it prints the last
`--last` steps: |e| per axis (mm), the tool's angle to the target (deg), the clearance of
the arm to its nearest contact (mm), whether the step collided, the largest joint move the
deployed policy commanded and the one it would command without its collision guard, and a
flag where the guard changed the step. A parked arm shows a constant row with the guarded
move 0; an arm pressed into a contact shows negative clearance and a collision on every
step; a cycle shows repeating rows.

    python benchmarks/episode_trace.py RUN/seed_S [--eval_seed 1000] [--episodes 10]
        [--steps 300] [--last 12] [--episode K ...] [--json OUT [--overwrite]]

(benchmarks/NOTES.md section 52: study 52's lost episodes, MARACollisionOrient's seed 1519
and the distill students stuck in contact.)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np


def trace(run: Path, eval_seed: int, episodes: int, steps: int) -> dict[str, np.ndarray]:
    """Per step (steps, episodes, ...) arrays of the deterministic policy's episodes."""
    from mara_mjx.envs.clearance import clearance
    from mara_mjx.ppo import checkpoint as ckpt
    from mara_mjx.ppo import policy as policy_io
    from mara_mjx.ppo.config import EvalConfig
    from mara_mjx.ppo.evaluation import episode_plan, with_collision_guard
    from mara_mjx.runtime import runs

    arrays, meta = ckpt.load_checkpoint(ckpt.find_checkpoint(run))
    env = runs.make_env(meta)
    policy = policy_io.policy_from_checkpoint(arrays, meta)
    bare = with_collision_guard(policy, 0.0)
    params, keys = episode_plan(env, EvalConfig(seed=eval_seed, episodes=episodes))
    n = env.action_size

    @jax.jit
    def run_all(keys):
        state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)

        def body(state, _):
            q = state.obs[..., :n]
            action, free = policy(state.obs), bare(state.obs)
            nxt = jax.vmap(env.step)(state, action)
            row = {
                "e_mm": 1000.0 * nxt.metrics["position_error"],
                "angle_deg": jnp.degrees(nxt.metrics["angle"]),
                "clearance_mm": 1000.0 * clearance(nxt.obs[..., :n]),
                "collided": nxt.metrics["collided"],
                "move": jnp.max(jnp.abs(action - q), -1),
                "move_unguarded": jnp.max(jnp.abs(free - q), -1),
                "guarded": jnp.max(jnp.abs(action - free), -1) > 1e-6,
            }
            return nxt, row

        return jax.lax.scan(body, state, None, length=steps)[1]

    return {k: np.asarray(v) for k, v in run_all(keys).items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path)
    p.add_argument("--eval_seed", type=int, default=1000)
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--last", type=int, default=12)
    p.add_argument("--episode", type=int, nargs="*", default=None)
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--overwrite", action="store_true", help="--json may replace any file")
    args = p.parse_args(argv)
    from mara_mjx.cli.common import UserError
    from mara_mjx.runtime import files, outputs

    if args.json:  # a new file (or --json's own earlier output), checked before the work
        try:
            ours = lambda path: outputs.written_by(path, COMMAND)  # noqa: E731
            outputs.check_output(args.json, "--json report", ours, args.overwrite)
        except UserError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
    rows = trace(args.run, args.eval_seed, args.episodes, args.steps)
    e_end = rows["e_mm"][-1]  # (episodes, 3)
    missed = [int(i) for i in np.where(~np.all(e_end <= 5.0, -1))[0]]
    shown = args.episode if args.episode is not None else missed
    print(f"{args.run}: evaluation seed {args.eval_seed}, {args.episodes} episodes, "
          f"{args.steps} steps; not within 5 mm at the end: {missed or 'none'}")  # fmt: skip
    for i in shown:
        print(f"episode {i}: step | e x, y, z mm | angle deg | clearance mm | collided | "
              "move (rad) | unguarded | guard acted")  # fmt: skip
        for t in range(max(0, args.steps - args.last), args.steps):
            e = rows["e_mm"][t, i]
            print(f"  {t:4d} | {e[0]:8.2f} {e[1]:8.2f} {e[2]:8.2f} | {rows['angle_deg'][t, i]:6.2f}"
                  f" | {rows['clearance_mm'][t, i]:7.2f} | {int(rows['collided'][t, i])}"
                  f" | {rows['move'][t, i]:.4f} | {rows['move_unguarded'][t, i]:.4f}"
                  f" | {'yes' if rows['guarded'][t, i] else ''}")  # fmt: skip
    if args.json:
        record = {
            "command": COMMAND,
            "run": str(args.run),
            **{k: v.tolist() for k, v in rows.items()},
        }
        files.write_atomic(args.json, json.dumps(record))
    return 0


COMMAND = "python benchmarks/episode_trace.py"


if __name__ == "__main__":
    sys.exit(main())
