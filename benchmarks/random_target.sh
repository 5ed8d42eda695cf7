#!/usr/bin/env bash
# The random-target tasks through the CLIs: train, then evaluate 1,000 held-out poses.
# Train with the default preset, then evaluate 1,000
# held-out target poses with the train driver and with the real driver at 0.3 rad/s.
#   python -m mara_mjx.train --env TASK --out OUT/TASK --progress false [TRAIN_FLAGS]
#   python -m mara_mjx.evaluate OUT/TASK --json OUT/TASK-train.json
#   python -m mara_mjx.evaluate OUT/TASK --driver real --velocity 0.3 --json OUT/TASK-real.json
# Each evaluation writes .json, .md (the per-axis table and a summary row) and .png (error
# over the workspace) side by side; train.log keeps the wall-clock from command start
# ("time to ..." lines), measured by the train CLI itself, and `date` brackets each run.
# Usage: bash benchmarks/random_target.sh OUT_DIR "TRAIN_FLAGS" [TASK ...]
#   e.g. bash benchmarks/random_target.sh benchmarks/results/random_target "" \
#          MARACollisionOrientRandomTarget
set -u
out=${1:-/tmp/random_target}; shift || true
flags=${1:-}; shift || true
tasks=${*:-MARACollisionOrientRandomTarget MARAOrientRandomTarget MARACollisionRandomTarget MARARandomTarget}
mkdir -p "$out"
for task in $tasks; do
  echo "== $task: start $(date -u +%FT%TZ)"
  start=$(date +%s)
  # shellcheck disable=SC2086  # TRAIN_FLAGS is a list of flags
  python3 -m mara_mjx.train --env "$task" --out "$out/$task" --progress false \
    --checkpoint_every 100000 $flags \
    2>&1 | tee "$out/$task.train.log" | grep -E "time to|reached the tolerance|steps/s"
  echo "train wall-clock $(( $(date +%s) - start )) s" | tee -a "$out/$task.train.log"
  python3 -m mara_mjx.evaluate "$out/$task" --json "$out/$task-train.json" \
    | tee "$out/$task-train.log" | grep -E "^\| $task|within"
  python3 -m mara_mjx.evaluate "$out/$task" --driver real --velocity 0.3 \
    --json "$out/$task-real.json" | tee "$out/$task-real.log" | grep -E "^\| $task|within"
  echo "== $task done $(date -u +%FT%TZ)"
done
