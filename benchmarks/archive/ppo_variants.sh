#!/usr/bin/env bash
# Does the policy stay at the target? Policy-parametrisation variants (benchmarks/NOTES.md,
# section 6). Every run: MARACollisionOrient, the default preset (2048 envs x 32 steps,
# reward scale 0.01), 6e7 env steps, deterministic XLA ops, so each is comparable with the
# `det` run of ppo_stability.sh (absolute actions, no floor, no entropy bonus).
#   rel        --relative_actions true (mean = current q + actor output)
#   floor      --log_std_floor -4.6 (sigma >= 0.01 rad)
#   ent        --ent_coef 0.005
#   relfloor   both relative actions and the floor
#   novel      --hidden_obs 13 14 15 (the networks do not see the TCP velocity)
#   relnovel   relfloor and novel
#   relfloorg9 relfloor with --gamma 0.9
# Then benchmarks/hold_trace.py on every run: per-step distance of one deterministic
# episode to the horizon and the paper's evaluation run to the horizon.
# Usage: bash benchmarks/archive/ppo_variants.sh OUT_DIR [NAME ...]
set -u
out=${1:-/tmp/ppo_variants}; shift || true
names=${*:-rel floor ent relfloor}
base=(--env MARACollisionOrient --total_timesteps 60000000 --progress false
      --checkpoint_every 100000 --plots false)
declare -A extra=(
  [base]=""
  [rel]="--relative_actions true"
  [floor]="--log_std_floor -4.6"
  [ent]="--ent_coef 0.005"
  [relfloor]="--relative_actions true --log_std_floor -4.6"
  [novel]="--hidden_obs 13 14 15"
  [relnovel]="--relative_actions true --log_std_floor -4.6 --hidden_obs 13 14 15"
  [relfloorg9]="--relative_actions true --log_std_floor -4.6 --gamma 0.9"
)
for name in $names; do
  # shellcheck disable=SC2086
  timeout 120 python3 -m mara_mjx.train "${base[@]}" --out "$out/$name" ${extra[$name]} 2>&1 \
    | grep -E "time to|reached the tolerance|\| MARA|steps/s" ; echo "== $name done"
done
dirs=(); for name in $names; do dirs+=("$out/$name"); done
python3 benchmarks/hold_trace.py "${dirs[@]}"
