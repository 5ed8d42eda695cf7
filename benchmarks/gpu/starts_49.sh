#!/bin/bash
# GPU driver (issues 31 and 32; NOTES section 49): the plan's restarts with the clearance
# check (a restart's landing taken only where the servos' path to it keeps 2 mm from every
# contact, the shortest of those) on MARACollisionOrientRandomTarget seeds trained WITHOUT a
# pick, fresh seeds. One argument per GPU (CUDA_VISIBLE_DEVICES); an argument is one or
# more specs joined by "+", run in turn on that GPU; a spec is "NAME OFFSET KIND [K...]":
#   KIND R  the any-pose recipe `cli --randomize --train_clearance_penalty 1 --plan_steps 16
#           --commit_rad 0.01`: 1,000 held-out poses (train driver) and 1,000 randomised
#           draws per speed on the real driver (0.3, 0.5 rad/s), 16 seeds' checkpoints kept;
#   KIND R2 the recipe at twice its budget (--total_timesteps 240000000; issue 31's "still
#           so when trained for twice its budget"), judged as R;
#   KIND P  the same without --randomize (the plain recipe);
#   KIND C  the task's CLI default (`cli`): 1,000 held-out poses on the train driver.
#   K...    judged with --plan_starts K for each K in turn on the same training (the first
#           study trains; the second reuses its run: same --work_dir and train command);
#           without a K, judged as trained (for C: the preset's own plan and restarts).
# Evaluation seed 1000. Launch with setsid (as starts_47.sh) and follow with poll.sh in the
# NEXT call:
#   bash benchmarks/gpu/starts_49.sh "rec_c 1456 R 16 8" "plain_c 1472 P 16 8+cli_c 1488 C"
# Results in /tmp/res/*.tgz.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
R="cli --randomize --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01"
P="cli --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01"
one() {  # NAME OFFSET KIND [K...]
  local n=$1 offset=$2 kind=$3 recipe real k
  shift 3
  case $kind in
    R) recipe=$R; real="--real_driver --rate_limit false" ;;
    R2) recipe="$R --total_timesteps 240000000"; real="--real_driver --rate_limit false" ;;
    P) recipe=$P; real="--real_driver --rate_limit false" ;;
    C) recipe=cli; real="" ;;
  esac
  [ $# -eq 0 ] && judged $n /tmp/work/$n "$recipe" --seed_offset $offset $real
  for k in "$@"; do
    judged ${n}_s$k /tmp/work/$n "$recipe" --seed_offset $offset $real --plan_steps 16 --plan_starts $k
  done
  [ $kind = C ] && return
  keep "$(ls -d /tmp/work/$n/runs/*/ | head -1)" /tmp/res/ck_$n.tgz
}
n=$(nvidia-smi -L | wc -l)
i=0
for arg in "$@"; do
  [ $i -ge $n ] && break
  (export CUDA_VISIBLE_DEVICES=$i
   IFS=+ read -ra specs <<< "$arg"
   for spec in "${specs[@]}"; do one $spec; done) &
  i=$((i + 1))
done
wait
echo DRIVER_DONE >> /tmp/res/studies.log
