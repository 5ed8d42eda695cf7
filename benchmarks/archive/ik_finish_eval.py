"""Would an IK finish fix the position tasks' entry error? (issue 11; NOTES section 27)

The saved policies of a position task (`orientation_study.py --save-params`), evaluated as
saved and with their joint targets replaced by the IK step (`task_space.pose_step`,
position only) within 6 cm (or 15 cm) of the target, directly or first to 1 cm short of
it, on two sets of evaluation episodes:

    python benchmarks/archive/ik_finish_eval.py MARA benchmarks/results/paper_table/params/MARA

CPU, a few minutes. An experiment, not a policy option.
"""

from __future__ import annotations

import os
import sys
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

import mara_mjx
from mara_mjx.envs.task_space import pose_step
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import make_evaluate

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # benchmarks/
from orientation_study import seed_row  # noqa: E402
from random_target_study import load_saved_policy  # noqa: E402


@struct.dataclass
class Finish:
    """A saved policy whose joint targets within `radius` (m) of the target are the IK
    step's (q + pose_step(q, e)); with `hold` > 0 that step aims `hold` short of the
    target until the TCP is within 1.2 x hold (a last Newton step from 1 cm)."""

    inner: Any
    radius: float = struct.field(pytree_node=False)
    hold: float = struct.field(pytree_node=False, default=0.0)

    def __call__(self, obs: jax.Array) -> jax.Array:
        mean = self.inner(obs)
        q, e = obs[..., :6], obs[..., 6:9]
        dist = jnp.linalg.norm(e, axis=-1, keepdims=True)
        if self.hold > 0.0:  # first to `hold` short of the target, then the full step
            e = jnp.where(dist > 1.2 * self.hold, e * (1.0 - self.hold / dist), e)
        return jnp.where(dist < self.radius, q + pose_step(q, e), mean)


def main() -> None:
    task, folder = sys.argv[1], sys.argv[2]
    seeds = range(5) if len(sys.argv) < 4 else [int(s) for s in sys.argv[3:]]
    env = mara_mjx.make(task)
    for eval_seed in (0, 3):
        stop = jax.jit(make_evaluate(env, EvalConfig(seed=eval_seed)))
        hold = jax.jit(make_evaluate(env, EvalConfig(tolerance_mm=0.0, seed=eval_seed)))
        for radius, hold_at in ((0.0, 0.0), (0.06, 0.0), (0.06, 0.01), (0.15, 0.01)):
            rows = []
            for seed in seeds:
                policy = Finish(load_saved_policy(folder, seed), radius, hold_at)
                rows.append(seed_row(jax.device_get(stop(policy)), jax.device_get(hold(policy))))
            pos = np.array([r["position_mm"] for r in rows])
            held = np.array([r["hold_position_mm"] for r in rows])
            print(
                f"{task} eval seed {eval_seed}, IK finish within {radius} m (first to "
                f"{hold_at} m short): reached "
                f"{sum(r['reached'] for r in rows)}/{10 * len(rows)}, position mean "
                f"{pos.mean(0).round(2).tolist()} worst {pos.max(0).round(2).tolist()} mm, "
                f"hold worst {held.max(0).round(3).tolist()} mm, collisions "
                f"{max(r['collisions'] for r in rows)} / hold "
                f"{max(r['hold_collisions_per_episode'] for r in rows)}",
                flush=True,
            )


if __name__ == "__main__":
    main()
