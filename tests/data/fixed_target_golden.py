"""Writes fixed_target_golden.npz: reset and 4 steps of each fixed-target task (train
driver), the values `tests/test_envs.py` requires bit-for-bit.

It was run once on commit c6cf3b4, before the random-target tasks existed, on the CPU:

    git archive c6cf3b4 | tar -x -C /tmp/orig
    JAX_PLATFORMS=cpu PYTHONPATH=/tmp/orig python3 tests/data/fixed_target_golden.py OUT.npz

Do not regenerate it to make a failing test pass: a difference means the fixed-target
tasks changed.
"""

from __future__ import annotations

import dataclasses
import sys

import jax
import jax.numpy as jnp
import numpy as np

import mara_mjx
from mara_mjx.envs.base import METRIC_KEYS

TASKS = ("MARA", "MARAOrient", "MARACollision", "MARACollisionOrient")
SPEC_REACH = (1.3338, -1.5341, -0.7833, 0.0, 2.3903, -0.237)
TABLE_FOLD = (0.0, 2.0, 0.0, 0.0, 0.0, 0.0)


def actions() -> np.ndarray:
    """(4, 6): near the spec's solution, a random pose, a table collision, random."""
    rng = np.random.default_rng(0)
    random = rng.uniform(-1.0, 1.0, (2, 6)).astype(np.float32)
    return np.stack([SPEC_REACH, random[0], TABLE_FOLD, random[1]]).astype(np.float32)


def rollout(reset, step, params) -> dict[str, np.ndarray]:
    """obs, reward and every metric of the reset and of 4 steps, stacked (5, ...)."""
    state = reset(jax.random.key(7), params)
    states = [state]
    for a in actions():
        state = step(state, jnp.asarray(a))
        states.append(state)
    out = {"obs": np.stack([np.asarray(s.obs) for s in states])}
    out["reward"] = np.stack([np.asarray(s.reward) for s in states])
    for k in METRIC_KEYS:
        out[k] = np.stack([np.asarray(s.metrics[k]) for s in states])
    return out


def main(path: str) -> None:
    arrays = {}
    # The MJX path, which the recording used: since the lean pass became the train
    # driver's default (EnvConfig.kinematics) it is chosen explicitly; the lean pass is
    # checked against MJX in tests/test_lean.py. (The recording's code had no such flag.)
    config_names = {f.name for f in dataclasses.fields(mara_mjx.EnvConfig)}
    mjx = {"kinematics": "mjx"} if "kinematics" in config_names else {}
    for name in TASKS:
        env = mara_mjx.make(name, **mjx)
        params = env.make_params(reset_noise=0.1)
        for k, v in rollout(jax.jit(env.reset), jax.jit(env.step), params).items():
            arrays[f"{name}/{k}"] = v
    arrays["jax_version"] = np.array(jax.__version__)
    arrays["backend"] = np.array(jax.default_backend())
    np.savez(path, **arrays)


if __name__ == "__main__":
    main(sys.argv[1])
