"""Measured throughput of mara_mjx: `python -m mara_mjx.benchmark STUDY [options]`.

Studies:
  env   env steps/s of the batched, jitted, auto-resetting step (`BatchedEnv.step`
        inside a `lax.scan`, random joint targets drawn inside the scan) for each task
        and driver over a sweep of environment counts. Compile time (first call) is
        reported apart from the steady state (median of `--repeats` timed calls after a
        warm-up). For the real driver, physics steps/s = env steps/s x substeps.
  peers C MuJoCo vs MJX on the same model, at each of `--sizes` env counts.
        Train driver: C MuJoCo mj_kinematics + mj_collision for random joint targets
        in one process per CPU core (`mara_mjx/bench/cpeer.py`) against the env
        study's timing of the MJX train driver.
        Real driver:
        What is compared: the `real` driver's work. C side: `mujoco.rollout.rollout`
        (nthread = os.cpu_count(), one MjData per thread, persistent thread pool) of
        N arms x `--steps` env steps x 10 substeps of mj_step (5 ms, implicitfast,
        Newton, the model's contacts and position+velocity servos), open loop, with
        the controls the real driver would send: per env step uniform random joint
        targets, the servo reference moving toward them at `velocity` rad/s,
        ctrl = [ref, ref_vel] (built in numpy beforehand, not timed). MJX side: the
        `env` study's timing of `BatchedEnv.step` with the real driver solving
        contacts as C does (MARA task, real_contacts='physical'; the default only
        detects them) for the same N and steps, which does the same 10 mjx.step
        substeps plus what C rollout does not: the final kinematics + collision for
        the pose, observation, reward, penetration checks and auto-reset. So the ratio
        MJX / C slightly favours C. Reported: env steps/s and physics steps/s (env
        steps x 10) of both, and MJX / C (env steps/s ratio) on the MJX row.
        `--skip_mjx` times the C sides only (the MJX real-driver compile takes about
        35 s on a CPU). The PPO peer is the `brax` study.
  train our PPO end to end on each task (`--preset`, default "default"; `--total`,
        `--num_envs`, ... override it): compile time apart, env steps/s including
        learning, and error (mm) against wall-clock after every jitted call of
        `--updates_per_call` updates, both the training metric `det_error_mm` and the
        common scorer's settled error; time to 5 mm and 1 mm; at the end the paper's
        evaluation (stop at 5 mm) and the same to the horizon. (`mara_mjx.bench.ppo`)
  brax  brax's PPO (`brax.training.agents.ppo`) on `make_brax_env(task)` against ours,
        same task, same env steps, hyperparameters from the same PPOConfig (as far as
        brax allows: `mara_mjx.bench.ppo.brax_kwargs`). Both keep (wall-clock, params) snapshots
        during training; after training every snapshot is scored by one common scorer
        (the deterministic policy for `--score_steps` steps from `--score_episodes`
        noisy resets, mean per-axis error over the last `--score_last` steps). Reported:
        env steps/s during training, wall-clock to 5 mm and 1 mm (compile excluded),
        and the ratios. (`mara_mjx.bench.ppo`; the clocks: `mara_mjx.bench.ppo_runs`)
  limit FLOPs and bytes of one env step (XLA's cost analysis: estimates) against the
        device's ceilings measured in the same run (float32 HIGHEST and bfloat16
        matmul FLOP/s, elementwise memory bandwidth): the roofline bound on env
        steps/s, the measured env steps/s (as in `env`) and the fraction reached, for
        `--tasks` x `--drivers` x `--sizes` / `--real_sizes`. (`mara_mjx.bench.limit`)

  tta   time to accuracy from command start, as users see it: for each of `--seeds`
        (default 0 1 2) the train CLI (`python -m mara_mjx.train --env TASK --seed S`,
        MARACollisionOrient, the task's preset unless `--preset`) as a fresh process, cold (an empty
        compilation-cache folder) and warm (the same folder again): seconds from
        launching it to a deterministic mean per-axis error below 5 mm and 1 mm, the
        whole command, env steps/s, a hash of the final state; medians over seeds. Then
        the PPO's env steps/s with XLA's deterministic GPU ops and without; the same
        command with `--seeds N` for each of `--seed_counts` (default 16: many seeds in
        one program, the way to fill a GPU), cold and warm, its env steps/s summed over
        the seeds and whether every seed's bits repeat; and the env step's FLOPs and
        bytes against the device's measured ceilings (the `limit` study's code, one
        size); last, the peers on the same machine: C MuJoCo doing the train driver's
        work on every CPU core at that size, and brax's PPO against ours (the `brax`
        study, `--peers_total_timesteps` env steps each). (`mara_mjx.bench.tta`)

scaling  env steps/s of the batched step and of PPO against the number of devices
        (1, 2, 4, ... all; weak scaling with a fixed per-device batch, and strong
        scaling of the default PPO batch), with the efficiency per added device
        (`mara_mjx/bench/scaling.py`). The other studies use every device the machine
        has (`BatchedEnv`'s default), so on a multi-GPU host their numbers are per host.

Output: a table on the terminal, and in `--out` (default runs/benchmarks/ under the working
directory; the recorded results are in benchmarks/results/):
  <study>.json (records + device, versions, settings, command), <study>.md, <study>.png.
`--quick` runs tiny sizes for a CPU smoke test (a --quick run never replaces a full one).
Each study's flags are generated from its config dataclass (`python -m mara_mjx.benchmark
STUDY --help`); the studies live in `mara_mjx/bench/`, one module each. Matmuls run in
float32 at HIGHEST precision; XLA's non-deterministic (faster) GPU ops are used unless
`--deterministic`.
"""

from __future__ import annotations

from collections.abc import Sequence

from mara_mjx.bench.runner import main as _main


def main(argv: Sequence[str] | None = None) -> None:
    _main(argv, description=__doc__)


if __name__ == "__main__":
    import sys

    from mara_mjx.runtime import supervise

    sys.exit(supervise.run(lambda: main() or 0, "mara_mjx.benchmark"))
