#!/usr/bin/env bash
# The four fixed-target tasks with the default preset, then hold_trace.py (README training table).
#   python -m mara_mjx.train --env TASK --preset default --out OUT/TASK --progress false
#   (seed 0, 5e7 steps; --preset default since each task has its own preset now)
# then benchmarks/hold_trace.py on every run (does the policy stay at the target; the
# paper's evaluation run to the horizon).
# Usage: bash benchmarks/ppo_final.sh OUT_DIR [TASK ...]
set -u
out=${1:-/tmp/ppo_final}; shift || true
tasks=${*:-MARA MARAOrient MARACollision MARACollisionOrient}
for task in $tasks; do
  timeout 150 python3 -m mara_mjx.train --env "$task" --preset default --out "$out/$task" --progress false \
    --checkpoint_every 100000 2>&1 | grep -E "time to|reached the tolerance|\| MARA|steps/s"
  echo "== $task done"
done
dirs=(); for task in $tasks; do dirs+=("$out/$task"); done
python3 benchmarks/hold_trace.py "${dirs[@]}"
