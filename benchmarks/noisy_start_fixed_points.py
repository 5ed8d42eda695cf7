"""Where a fixed-target policy ends from the paper evaluation's noisy starts: N episodes of
the deployed deterministic policy (its checkpoint's rules; train driver) from the reset
pose plus uniform joint noise, each run for a fixed number of steps, and for the ones
that end off the target, where (the TCP's distance and the joints they stand at), beside
the joints of those that land. Found the Orient tasks' CLI-default failures on fresh
seeds (benchmarks/NOTES.md section 60: fixed points of the learnt step from starts
training, which begins at the exact reset pose, never visits).

    python benchmarks/noisy_start_fixed_points.py RUN/seed_S [--starts 64] [--steps 300]
        [--noise 0.02] [--key 7] [--plan_steps K --plan_starts M] [--stochastic]

--plan_steps/--plan_starts override the checkpoint's deployed plan (-1: as trained).
--stochastic: the network's Gaussian sampled (mean + exp(log_std) noise, the deployed
network: without the training-only rules) instead of the deterministic policy, from the
same starts: does exploration leave a deterministic fixed point (NOTES section 65)?
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.evaluation import deployed_plan
from mara_mjx.ppo.policy import policy_from_checkpoint
from mara_mjx.ppo.run_config import EvalConfig
from mara_mjx.runtime import runs


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path, help="a seed's run folder or checkpoint")
    p.add_argument("--starts", type=int, default=64)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--noise", type=float, default=0.02, help="reset noise (rad)")
    p.add_argument("--key", type=int, default=7)
    p.add_argument("--tolerance_mm", type=float, default=5.0)
    p.add_argument("--plan_steps", type=int, default=-1)
    p.add_argument("--plan_starts", type=int, default=-1)
    p.add_argument("--stochastic", action="store_true")
    a = p.parse_args(argv)
    jax.config.update("jax_default_matmul_precision", "highest")
    arrays, meta = ckpt.load_checkpoint(ckpt.find_checkpoint(a.run))
    plan = EvalConfig(plan_steps=a.plan_steps, plan_starts=a.plan_starts)  # evaluate's
    policy = deployed_plan(policy_from_checkpoint(arrays, meta), plan)
    env = runs.make_env(meta)
    params = env.make_params(reset_noise=a.noise)
    keys = jax.random.split(jax.random.key(a.key), a.starts)
    state = jax.vmap(lambda k: env.reset(k, params))(keys)
    if a.stochastic:

        def act(s, k):
            mean, log_std = policy.distribution(s.obs)
            return mean + jax.numpy.exp(log_std) * jax.random.normal(k, mean.shape)

        step = jax.jit(jax.vmap(lambda s, k: env.step(s, act(s, k))))
    else:
        step = jax.jit(jax.vmap(lambda s, k: env.step(s, policy(s.obs))))
    noise_key = jax.random.key(a.key + 1)
    for i in range(a.steps):
        state = step(state, jax.random.split(jax.random.fold_in(noise_key, i), a.starts))
    mm = 1000.0 * np.asarray(state.metrics["distance"])
    q = np.asarray(state.obs[:, :6])
    off = mm > a.tolerance_mm
    np.set_printoptions(precision=2, suppress=True, linewidth=120)
    print(f"{a.run}: {int(off.sum())} of {a.starts} starts end more than {a.tolerance_mm:g} mm "
          f"off after {a.steps} steps (reset noise {a.noise:g} rad, key {a.key})")  # fmt: skip
    if off.any():
        print(f"  their distance (mm): {np.round(np.sort(mm[off]), 1)}")
        print(f"  their joints (rad), median: {np.median(q[off], axis=0)}")
    if (~off).any():
        print(f"  the others' joints (rad), median: {np.median(q[~off], axis=0)}")
    collisions = np.asarray(state.metrics["collisions"])[off].sum()
    print(f"  collisions in the episodes that end off: {collisions:g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
