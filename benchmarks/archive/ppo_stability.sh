#!/usr/bin/env bash
# PPO stability and reproducibility on one GPU (benchmarks/NOTES.md, section 4).
# Every run: MARACollisionOrient, 2048 envs x 32 steps, reward scale 0.01, 6e7 env steps.
#   det, det2    the same seed twice with deterministic XLA GPU ops (the CLI's default)
#   nondet       the same with --xla_gpu_deterministic_ops=false (speed cost of determinism)
#   lr1e-4       learning rate 1e-4 instead of 3e-4
#   noadvnorm    no per-minibatch advantage normalisation
# Usage: bash benchmarks/archive/ppo_stability.sh OUT_DIR   (progress.csv + summary.json per run)
set -u
out=${1:-/tmp/ppo_stability}
base=(--env MARACollisionOrient --num_envs 2048 --num_steps 32 --num_minibatches 32
      --reward_scale 0.01 --total_timesteps 60000000 --progress false --checkpoint_every 100000)
run() { name=$1; shift; timeout 110 python3 -m mara_mjx.train "${base[@]}" --out "$out/$name" "$@" \
          2>&1 | grep -E "time to|reached the tolerance|\| MARA" ; echo "== $name done"; }
run det
run det2
XLA_FLAGS="${XLA_FLAGS:-} --xla_gpu_deterministic_ops=false" run nondet
run lr1e-4 --learning_rate 1e-4
run noadvnorm --normalize_advantages false
