#!/bin/bash
# GPU driver (issue 32 item 3, issue 31's random-target row; NOTES section 44): the any-pose
# real-arm recipe with the plan and held commands, a pick of 4 among seeds, the exported
# files in evaluate's loop. Launch with setsid and follow with poll.sh.
#   bash anypose_44.sh A   GPU: MARACollisionOrientRandomTarget `cli --randomize
#     --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01`, 8 picks of 4 among 32
#     fresh seeds (1232-1263; chosen on the real driver, 200 draws per speed of selection
#     seed 1001), each pick judged on 1,000 held-out poses (train driver) and 1,000 draws
#     per speed (real driver, 0.3 and 0.5 rad/s), evaluation seed 1000; the picks'
#     checkpoints kept and exported to .onnx. CPU beside it, one cell per core
#     (benchmarks/deploy_sweep.py, 1,000 episodes a cell): section 42's seed-1164 file with
#     held commands (--commit_rad 0.01) at latency 0-3 steps and zero offsets 0-4 mrad,
#     and section 42's 16 files held, randomised, at both speeds (the recipe without a
#     pick). Then the picks' files in the loop at both speeds.
#   bash anypose_44.sh picks NAME OFFSET ["RECIPE"]   the same (RECIPE: default $R, A's) for 32 seeds
#     from OFFSET, without the CPU cells of section 42's files: for the next device session,
#     `picks mcort_sel2 1264` (8 more picks: 16 in all) and `picks plain 1296 "cli
#     --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01"` (the plain recipe:
#     no randomised physics in training, judged with it). One per machine (~25 minutes).
#   bash anypose_44.sh gpus   the same two on a machine of several GPUs, split: on GPU i
#     (CUDA_VISIBLE_DEVICES, the study, its exports' checks and its loops) the i-th of
#     mcort_sel2a 1264, mcort_sel2b 1280 (the recipe's 8 more picks), plain_a 1296, plain_b
#     1312 (the plain recipe's 8), each 4 picks of 4 among 16 seeds (about 12 minutes of
#     training on one H200); with fewer GPUs, the first ones only (section 45).
#   bash anypose_44.sh gpus "NAME OFFSET R|P"...   the same for the studies given (R: the
#     recipe, P: the plain one); for the selection with the train driver's poses (section
#     45, built after that run): gpus "tsel_a 1328 R" "tsel_b 1344 R" "tsel_c 1360 R"
#     "tsel_d 1376 R" (16 picks of 64 fresh seeds, one 4-GPU machine, about 22 minutes).
# A needs section 42's files carried as sweep_in/onnx42.tgz (carry "sweep_in": it is
# excluded from git, 3.4 MB). On the run of section 44 the held42 cells were stopped by
# hand after 4 (device time); only the sweep and the picks' cells completed.
# Results in /tmp/res/*.tgz (cells_*.tgz: one deploy_sweep folder per cell).
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
R="cli --randomize --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01"
picks() {  # NAME OFFSET RECIPE [N]: N (8) picks of 4 among 4N seeds from OFFSET, exported, in the loop
  local n=$1 offset=$2 recipe=$3 k=${4:-8} run p
  mcort $n "$recipe" --seeds $k --seed_offset $offset --select 4
  run=$(ls -d /tmp/work/$n/runs/*/ | head -1)
  p=$(picks_of $n)
  [ -n "$p" ] || { echo "picks $n: the study judged no seed (see $n.log)" >> /tmp/res/studies.log; return 1; }
  keep "$run" /tmp/res/ck_$n.tgz $p
  export_all "$run" /tmp/res/onnx_$n $p
  wait  # (A: the CPU cells started beside the training)
  loops $n "MARACollisionOrientRandomTarget, $recipe, pick of 4, exported .onnx" 14
}
case $1 in
  A)
    mkdir -p /tmp/onnx42 && tar xzf sweep_in/onnx42.tgz -C /tmp/onnx42
    f=/tmp/onnx42/policy_1164.onnx
    L="MARACollisionOrientRandomTarget, cli --randomize --train_clearance_penalty 1 --plan_steps 16 (section 42), exported .onnx, held in the loop (--commit_rad 0.01)"
    for v in 0.3 0.5; do
      for k in 0 1 2 3; do
        printf '%q ' "sw1164_${v}_lat$k" $f --label "$L" --velocities $v --randomised false --latencies $k --calibrations -- --commit_rad 0.01; echo
      done
      for c in 0 0.001 0.002 0.004; do
        printf '%q ' "sw1164_${v}_cal$c" $f --label "$L" --velocities $v --randomised false --latencies --calibrations $c -- --commit_rad 0.01; echo
      done
    done > /tmp/res/jobs_a
    for s in $(seq 1164 1179); do
      for v in 0.3 0.5; do
        printf '%q ' "held42_${s}_$v" /tmp/onnx42/policy_$s.onnx --label "$L" --velocities $v --latencies --calibrations -- --commit_rad 0.01; echo
      done
    done >> /tmp/res/jobs_a
    (cells /tmp/res/jobs_a 12
     tar czf /tmp/res/cells_a.tgz.part -C /tmp/res/cells $(cd /tmp/res/cells && ls -d sw1164_* held42_*) && mv /tmp/res/cells_a.tgz.part /tmp/res/cells_a.tgz) &
    picks mcort_sel 1232 "$R"
    ;;
  picks) picks "$2" "$3" "${4:-$R}" ;;
  gpus)  # one study of 4 picks (16 seeds) per GPU, in this order, as many as there are GPUs (<= 4)
    P="cli --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01"
    n=$(nvidia-smi -L | wc -l)
    i=0
    shift
    [ $# -gt 0 ] || set -- "mcort_sel2a 1264 R" "mcort_sel2b 1280 R" "plain_a 1296 P" "plain_b 1312 P"
    for spec in "$@"; do
      [ $i -ge $n ] && break
      set -- $spec
      r=$R; [ $3 = P ] && r=$P
      (export CUDA_VISIBLE_DEVICES=$i; picks $1 $2 "$r" 4) &
      i=$((i + 1))
    done
    wait
    ;;
  *) echo "usage: anypose_44.sh A | picks NAME OFFSET RECIPE | gpus" >&2; exit 2 ;;
esac
echo DRIVER_DONE >> /tmp/res/studies.log
