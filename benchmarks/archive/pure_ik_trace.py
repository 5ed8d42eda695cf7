"""The IK step alone (no policy) from the reset pose of a fixed-target task (issue 11):
where the TCP first enters the paper's 5 mm box and with what orientation error, with and
without `orient_first` (envs/task_space.pose_step; benchmarks/NOTES.md section 26). It
traces the deployed orient-first rule as committed (section 27's hold included), so
section 26's numbers, made with what is now the loose form, do not reproduce exactly.

    python benchmarks/archive/pure_ik_trace.py --task MARACollisionOrient [--orient-first] \
        [--steps 120]

CPU, seconds.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

import mara_mjx
from mara_mjx.envs import task_space


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="MARACollisionOrient")
    p.add_argument("--orient-first", action="store_true")
    p.add_argument("--steps", type=int, default=120)
    args = p.parse_args(argv)
    env = mara_mjx.make(args.task)
    index = next(int(x["start"]) for x in env.observation_layout if x["name"] == "quat_err")

    @jax.jit
    def step(state):
        q, e, quat = state.obs[:6], state.obs[6:9], state.obs[index : index + 4]
        dq = task_space.pose_step(q, e, quat, wrap_last=True, orient_first=args.orient_first)
        return env.step(state, q + dq)

    state, first = env.reset(jax.random.key(0)), None
    for t in range(args.steps):
        state = step(state)
        pos = 1000 * np.asarray(state.metrics["position_error"])
        ori = np.degrees(np.asarray(state.metrics["orientation_error"]))
        if first is None and (pos < 5).all():
            first = t
            print(f"first within 5 mm at step {t}: {pos.round(2)} mm, {ori.round(2)} deg")
    print(
        f"after {args.steps} steps: {pos.round(2)} mm, {ori.round(2)} deg, "
        f"collisions {int(state.metrics['collisions'])}"
    )


if __name__ == "__main__":
    main()
