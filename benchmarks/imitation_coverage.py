"""How close to the target an imitation run's rollouts come, per exploration noise: one
student's mean action plus Gaussian noise, env i of N with sigma as `--imitation_spread`
would give it (`mara_mjx.ppo.teacher.rollout_sigma`), from the env's reset, train driver;
the share of visited states within 1, 3 and 10 mm of the target and the median distance,
over the steps after the first `--skip`.

    python benchmarks/imitation_coverage.py STUDENT_SEED_FOLDER [--envs 256 --steps 300]

Noise settings compared: a floor of 0.01 rad (the distill preset's), a floor of 0.05
(`--log_std_floor -3`, study 60) and the spread 0.05 over a floor of 0.01
(`--imitation_spread 0.05`). benchmarks/NOTES.md section 55."""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.envs.batched import BatchedEnv
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.policy import policy_from_checkpoint
from mara_mjx.ppo.teacher import rollout_sigma
from mara_mjx.runtime import runs


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("student", type=Path)
    p.add_argument("--envs", type=int, default=256)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--skip", type=int, default=50)
    a = p.parse_args()
    arrays, meta = ckpt.load_checkpoint(ckpt.find_checkpoint(a.student))
    policy = policy_from_checkpoint(arrays, meta)
    env = BatchedEnv(runs.make_env(meta), a.envs)
    settings = {"floor 0.01": (0.01, 0.0), "floor 0.05": (0.05, 0.0), "spread 0.05": (0.01, 0.05)}
    for name, (floor, spread) in settings.items():
        log_std = jnp.full((a.envs, 6), jnp.log(floor))
        sigma = rollout_sigma(log_std, spread)

        def body(carry, key, sigma=sigma):
            state = carry
            action = policy(state.obs) + sigma * jax.random.normal(key, (a.envs, 6))
            state = env.step(state, action)
            return state, 1000.0 * jnp.linalg.norm(state.obs[:, 6:9], axis=-1)

        state = env.reset(jax.random.key(0))
        keys = jax.random.split(jax.random.key(1), a.steps)
        _, dist = jax.jit(lambda s, k: jax.lax.scan(body, s, k))(state, keys)
        d = np.asarray(dist[a.skip :]).ravel()
        within = ", ".join(f"{np.mean(d < r):.1%} within {r} mm" for r in (1, 3, 10))
        print(f"{name}: {within}; median {np.median(d):.1f} mm", flush=True)


if __name__ == "__main__":
    main()
