"""Where a student (`--preset distill`) settles near the target, and why: per seed of a
student run, at the target's joints q_t (where that seed's teacher settles: its
deterministic policy from the reset, train driver, 60 steps), the student's step there
b = F(q_t) - q_t, the eigenvalues of its closed loop's Jacobian dF/dq (0: back in one
step, as the IK teacher; 1: no correction), and the linear fixed point
q_t + (I - dF/dq)^-1 b as the TCP's offset per axis (mm), beside the study's hold error
where a robustness report is given.
F(q) is the deterministic policy at joints q, zero velocity, the task's default target.

    python benchmarks/student_fixed_point.py STUDENT_RUN TEACHER_RUN [--report robustness.json]

Found by a helper's analysis of study 60's students (benchmarks/NOTES.md section 55): the
linear fixed point matched the study's hold on all 32 students (correlation 0.996 and
0.958 over seeds and axes)."""

from __future__ import annotations

import argparse
import gzip
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.policy import policy_from_checkpoint
from mara_mjx.runtime import runs


def load(folder: Path):
    """A run's policy and meta: its one step (a deployed plan and its restarts cleared, as
    a teacher acts for its students: `mara_mjx.ppo.teacher`)."""
    arrays, meta = ckpt.load_checkpoint(ckpt.find_checkpoint(folder))
    return policy_from_checkpoint(arrays, meta).one_step(), meta


def observer(env, params):
    """q (6,) -> the observation at joints q, at rest (the task's default target)."""

    def obs(q):
        pose = env.arm.pose_with(q, env.kinematics, collide=False)
        return env._observe(q, pose, jnp.zeros(6), params)[0]

    return obs


def settled(env, params, teacher):
    """The joints where `teacher` settles: its deterministic policy from the reset, 60 steps
    (train driver)."""
    state = env.reset(jax.random.key(0), params)
    step = jax.jit(lambda s: env.step(s, teacher(s.obs)))
    for _ in range(60):
        state = step(state)
    return state.obs[:6]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("student", type=Path)
    p.add_argument("teacher", type=Path)
    p.add_argument("--report", type=Path, help="the study's robustness.json(.gz)")
    a = p.parse_args()
    jax.config.update("jax_default_matmul_precision", "highest")
    seeds = sorted(int(d.name[5:]) for d in a.student.glob("seed_*"))
    records = {}
    if a.report:
        opener = gzip.open if a.report.suffix == ".gz" else open
        with opener(a.report, "rt") as f:
            records = {r["seed"]: r for r in json.load(f)["records"] if r["kind"] == "seed"}

    def teacher_of(seed):  # student seed s learned from the teacher run's seed_s
        folder = a.teacher / f"seed_{seed}"
        return load(folder if folder.is_dir() else a.teacher)

    _, meta = teacher_of(seeds[0])
    env = runs.make_env(meta)
    params = env.make_params(reset_noise=0.0)

    obs = observer(env, params)
    preds, holds = [], []
    for seed in seeds:
        q_t = settled(env, params, teacher_of(seed)[0])
        student, _ = load(a.student / f"seed_{seed}")
        F = lambda q: student(obs(q))  # noqa: E731
        b = np.asarray(F(q_t) - q_t)
        J = np.asarray(jax.jacfwd(F)(q_t))
        eig = np.sort(np.abs(np.linalg.eigvals(J)))[::-1][:3]
        dq = np.linalg.solve(np.eye(6) - J, b)
        e = np.abs(1000 * np.asarray(obs(q_t + jnp.asarray(dq, q_t.dtype))[6:9]))
        off = np.abs(1000 * np.asarray(obs(q_t)[6:9])).max()  # the teacher's own, ~0
        line = (f"{seed}: teacher {off:.4f} mm off, |b| max {np.abs(b).max():.4f} rad, "
                f"|eig| {eig.round(3)}, linear fixed point {e.round(2)} mm")  # fmt: skip
        if seed in records:
            hold = np.array(records[seed]["hold"]["position_mm"])
            preds.append(e), holds.append(hold)
            line += f", study hold {hold.round(2)} mm"
        print(line, flush=True)
    if preds:
        pred, hold = np.ravel(preds), np.ravel(holds)
        print(
            f"correlation over seeds and axes {np.corrcoef(pred, hold)[0, 1]:.3f}, "
            f"median |prediction - hold| {np.median(np.abs(pred - hold)):.3f} mm"
        )


if __name__ == "__main__":
    main()
