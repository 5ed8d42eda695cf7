#!/bin/bash
# GPU driver (issues 31 and 32; NOTES section 47): the plan's restarts (PolicyConfig.plan_starts,
# deployed only) on MARACollisionOrientRandomTarget seeds trained WITHOUT a pick. Per GPU
# (CUDA_VISIBLE_DEVICES) one study of 16 fresh seeds, judged as trained and again with
# --plan_starts 8 on the same training (the second study reuses the first one's run:
# same --work_dir, same train command), evaluation seed 1000:
#   R  the any-pose recipe `cli --randomize --train_clearance_penalty 1 --plan_steps 16
#      --commit_rad 0.01`: 1,000 held-out poses (train driver) and 1,000 randomised draws
#      per speed on the real driver (0.3, 0.5 rad/s); the 16 checkpoints kept; with LOOPS=1
#      every seed exported with --plan_starts 8 and its .onnx in evaluate's loop at both
#      speeds (issue 32: every training seed, no pick). Since the restarts run side by
#      side (NOTES section 48) a file with 8 restarts is ~4 MB and exports in ~30 s on
#      this project's CPU; one onnxruntime call on 1,000 observations still takes ~2 s
#      on one thread, so a 1,000-episode cell is long: budget the loops as their own
#      call (about 30 cells per GPU's study, 14 at once), after the studies;
#   P  the same without --randomize (the plain recipe), the same judgements and loops;
#   C  the task's CLI default (`cli`, the random_target_orient preset): 1,000 held-out
#      poses on the train driver, as trained and with --plan_steps 16 --plan_starts 8
#      (issue 31's row).
# Launch with setsid (as anypose_44.sh) and follow with poll.sh in the NEXT call (a poll
# in the launching call can read the previous run's DRIVER_DONE before the driver clears
# studies.log):
#   bash benchmarks/gpu/starts_47.sh "rec_a 1392 R" "cli_a 1408 C" ["plain_a 1424 P" "rec_b 1440 R"]
# as many specs as GPUs are used (the first n on n GPUs). Results in /tmp/res/*.tgz.
# STARTS="8 16" judges each K in turn on the same training (NOTES section 48: 16 starts
# reached the poses 8 missed on the two recipe seeds still short), as NAME_sK.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
R="cli --randomize --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01"
P="cli --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01"
one() {  # NAME OFFSET KIND
  local n=$1 offset=$2 kind=$3 recipe real run
  case $kind in
    R) recipe=$R; real="--real_driver --rate_limit false" ;;
    P) recipe=$P; real="--real_driver --rate_limit false" ;;
    C) recipe=cli; real="" ;;
  esac
  judged ${n} /tmp/work/$n "$recipe" --seed_offset $offset $real
  local k
  for k in ${STARTS:-8}; do  # (STARTS="8 16": each K judged on the same training)
    if [ $kind = C ]; then
      judged ${n}_s$k /tmp/work/$n "$recipe" --seed_offset $offset --plan_steps 16 --plan_starts $k
    else
      judged ${n}_s$k /tmp/work/$n "$recipe" --seed_offset $offset $real --plan_starts $k
    fi
  done
  [ $kind = C ] && return
  run=$(ls -d /tmp/work/$n/runs/*/ | head -1)
  keep "$run" /tmp/res/ck_$n.tgz  # (16 seeds' checkpoints, ~28 MB: the loops can run later)
  [ "${LOOPS:-0}" = 1 ] || return 0
  k=${STARTS:-8}; k=${k##* }  # (the last K)
  EXPORT_FLAGS="--plan_starts $k" EXPORT_ONNX_TGZ=0 export_all "$run" /tmp/res/onnx_$n $(seq $offset $((offset + 15)))
  loops $n "MARACollisionOrientRandomTarget, $recipe, every seed (no pick), exported .onnx with --plan_starts $k" 14
}
n=$(nvidia-smi -L | wc -l)
i=0
for spec in "$@"; do
  [ $i -ge $n ] && break
  set -- $spec
  (export CUDA_VISIBLE_DEVICES=$i; one $1 $2 $3) &
  i=$((i + 1))
done
wait
echo DRIVER_DONE >> /tmp/res/studies.log
