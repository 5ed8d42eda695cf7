"""Where a student and its teacher take the TCP in one step near the target: per seed,
from the teacher's settled joints q_t (its deterministic policy from the reset, 60 steps,
the task's default target) moved along N random joint directions so that the TCP is r mm
off, each policy's next TCP error (median and 10% / 90% quantiles over the directions).
An IK teacher lands on the target (0); a student whose loop is slow keeps a share of r.

    python benchmarks/student_step_ratio.py STUDENT_RUN TEACHER_RUN --seeds 1504 [--mm 2 4 ...]

Showed that orient_first's map near the target is discontinuous, the students' slow loop
regressing across it (benchmarks/NOTES.md section 58)."""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from student_fixed_point import load, observer, settled

from mara_mjx.runtime import runs


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("student", type=Path)
    p.add_argument("teacher", type=Path)
    p.add_argument("--seeds", type=int, nargs="+", required=True)
    p.add_argument("--mm", type=float, nargs="+", default=[2, 4, 6, 8, 10, 12, 14, 17, 20])
    p.add_argument("--directions", type=int, default=256)
    a = p.parse_args()
    jax.config.update("jax_default_matmul_precision", "highest")
    for seed in a.seeds:
        teacher, meta = load(a.teacher / f"seed_{seed}")
        student, _ = load(a.student / f"seed_{seed}")
        env = runs.make_env(meta)
        params = env.make_params(reset_noise=0.0)

        obs = observer(env, params)
        q_t = settled(env, params, teacher)
        off = jax.jit(jax.vmap(lambda q: 1000 * jnp.linalg.norm(obs(q)[6:9])))  # mm
        nxt = {
            name: jax.jit(jax.vmap(lambda q, pi=pi: 1000 * jnp.linalg.norm(obs(pi(obs(q)))[6:9])))
            for name, pi in (("teacher", teacher), ("student", student))
        }
        d = np.random.default_rng(1).normal(size=(a.directions, 6))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        per_mrad = np.asarray(off(q_t + 1e-3 * d))  # mm per mrad along each direction
        print(f"seed {seed}: TCP off (mm) -> next step off, median (10% / 90%)")
        for mm in a.mm:
            q = q_t + (mm / per_mrad)[:, None] * 1e-3 * d
            row = f"  {np.median(np.asarray(off(q))):6.2f}"
            for name, f in nxt.items():
                e = np.asarray(f(q))
                lo, hi = np.quantile(e, 0.1), np.quantile(e, 0.9)
                row += f"  {name} {np.median(e):6.2f} ({lo:5.2f} / {hi:5.2f})"
            print(row, flush=True)


if __name__ == "__main__":
    main()
