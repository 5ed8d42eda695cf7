"""C MuJoCo doing the train driver's work on every CPU core: the `peers` study's
train-driver peer (`python -m mara_mjx.benchmark peers`).

What one env step is here: set the 6 joint positions to uniform random targets in the
joint box, `mj_kinematics`, `mj_collision` (the model's explicit contact pairs), which
is what the MJX train driver computes (kinematics + collision) minus the observation,
reward and auto-reset. `mujoco.rollout` has no kinematics-only mode, and the Python
bindings hold the GIL during these calls (2 threads ran slower than 1 on a 2-core CPU),
so the work is spread over one process per core (`multiprocessing`, "spawn"), each
looping over its share of the environments in Python with one MjData (a train-driver
step depends only on the joint targets, not on the previous state). The Python
loop adds about 1 of the ~5 microseconds one step takes on a 2-core CPU, so a C loop
would be somewhat faster: the ratio MJX / C favours MJX by up to ~20%.

Timing: the targets are drawn before the clock starts; every worker times its own loop,
and the call's time is the slowest worker's (`loop_s`); `wall_s` (parent side, with the
inter-process messages) is recorded too.
"""

from __future__ import annotations

import multiprocessing
import statistics
from typing import Any

import numpy as np

_MODEL = None


def _init(model: Any) -> None:
    global _MODEL
    _MODEL = model


def _work(job: tuple[int, int, int]) -> tuple[float, int]:
    """(seed, envs, steps) -> (loop seconds, colliding steps) in this worker process."""
    import time

    import mujoco

    seed, envs, steps = job
    m = _MODEL
    lower, upper = m.jnt_range[:6, 0], m.jnt_range[:6, 1]
    targets = np.random.default_rng(seed).uniform(lower, upper, (steps, envs, 6))
    d = mujoco.MjData(m)  # one suffices: a step depends only on the joint targets
    collided = 0
    t0 = time.perf_counter()
    for t in range(steps):
        for q in targets[t]:
            d.qpos[:6] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_collision(m, d)
            collided += d.ncon > 0
    return time.perf_counter() - t0, collided


class KinematicsPool:
    """A persistent pool of `nproc` worker processes holding the MuJoCo model."""

    def __init__(self, model: Any, nproc: int):
        self.nproc = nproc
        ctx = multiprocessing.get_context("spawn")
        self.pool = ctx.Pool(nproc, initializer=_init, initargs=(model,))

    def close(self) -> None:
        self.pool.close()
        self.pool.join()

    def time(self, num_envs: int, steps: int, repeats: int) -> dict[str, Any]:
        import time

        shares = [len(a) for a in np.array_split(np.arange(num_envs), self.nproc)]
        jobs = lambda r: [(r * 1000 + i, n, steps) for i, n in enumerate(shares) if n]  # noqa: E731
        loops, walls, collided = [], [], 0
        for r in range(repeats + 1):  # the first call warms up (imports, allocations)
            t0 = time.perf_counter()
            out = self.pool.map(_work, jobs(r))
            wall = time.perf_counter() - t0
            if r:
                loops.append(max(s for s, _ in out))
                walls.append(wall)
                collided += sum(c for _, c in out)
        loop = statistics.median(loops)
        return {
            "impl": f"mujoco C kinematics+collision ({self.nproc} processes)",
            "driver": "train",
            "device": f"cpu x{self.nproc}",
            "num_envs": num_envs,
            "steps_per_call": steps,
            "median_call_s": loop,
            "wall_s": statistics.median(walls),
            "env_steps_per_s": num_envs * steps / loop,
            "physics_steps_per_s": None,
            "collision_fraction": collided / (num_envs * steps * repeats),
            "mjx_over_c": None,
        }
