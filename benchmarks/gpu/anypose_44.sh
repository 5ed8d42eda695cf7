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
#   bash anypose_44.sh B   what A did not reach: the picks exported from sweep_in/ck_mcort_sel.tgz
#     (or their files from sweep_in/onnx_mcort_sel.tgz) and run in the loop; GPU beside it:
#     the plain recipe (no --randomize), 16 seeds from 1296, judged the same way.
# Results in /tmp/res/*.tgz (cells_*.tgz: one deploy_sweep folder per cell).
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
R="cli --randomize --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01"
mcort() {  # NAME RECIPE FLAGS...: a MARACollisionOrientRandomTarget study on the real driver
  local n=$1 recipe=$2
  shift 2
  python -m mara_mjx.benchmark robustness --eval_seed 1000 \
    --tasks MARACollisionOrientRandomTarget --recipes "$recipe" \
    --real_driver --rate_limit false "$@" --out /tmp/res/$n --work_dir /tmp/work/$n \
    > /tmp/res/$n.log 2>&1
  echo "$n DONE $?" >> /tmp/res/studies.log
  pack $n
}
picks() {  # NAME: the judged seeds of /tmp/res/NAME's study
  python -c "import json,sys; print(*[r['seed'] for r in json.load(open(sys.argv[1]))['records'] if r['kind'] == 'seed'])" /tmp/res/$1/robustness.json
}
export_all() {  # RUN OUT SEEDS...: each seed of RUN exported to OUT/policy_S.onnx, 8 at a time
  local run=$1 out=$2 i=0
  shift 2
  mkdir -p $out
  for s in "$@"; do
    JAX_PLATFORMS=cpu python -m mara_mjx.export "$run/seed_$s" $out/policy_$s.onnx > $out/export_$s.log 2>&1 &
    i=$((i + 1)); [ $((i % 8)) -eq 0 ] && wait
  done
  wait
  echo "export $(basename $out) DONE $(ls $out/*.onnx | wc -l)" >> /tmp/res/studies.log
  tar czf /tmp/res/$(basename $out).tgz.part -C /tmp/res $(basename $out) && mv /tmp/res/$(basename $out).tgz.part /tmp/res/$(basename $out).tgz
}
loops() {  # NAME LABEL P: every file of /tmp/res/onnx_NAME at both speeds, randomised
  for f in /tmp/res/onnx_$1/policy_*.onnx; do
    s=$(basename $f .onnx); s=${s#policy_}
    for v in 0.3 0.5; do
      echo "loop_${1}_${s}_$v $f --label '$2' --velocities $v --latencies --calibrations"
    done
  done > /tmp/res/jobs_loop_$1
  cells /tmp/res/jobs_loop_$1 $3
  tar czf /tmp/res/cells_loop_$1.tgz.part -C /tmp/res/cells $(cd /tmp/res/cells && ls -d loop_$1_*) && mv /tmp/res/cells_loop_$1.tgz.part /tmp/res/cells_loop_$1.tgz
}
case $1 in
  A)
    mkdir -p /tmp/onnx42 && tar xzf sweep_in/onnx42.tgz -C /tmp/onnx42
    f=/tmp/onnx42/policy_1164.onnx
    L="MARACollisionOrientRandomTarget, cli --randomize --train_clearance_penalty 1 --plan_steps 16 (section 42), exported .onnx, held in the loop (--commit_rad 0.01)"
    for v in 0.3 0.5; do
      for k in 0 1 2 3; do
        echo "sw1164_${v}_lat$k $f --label '$L' --velocities $v --randomised false --latencies $k --calibrations -- --commit_rad 0.01"
      done
      for c in 0 0.001 0.002 0.004; do
        echo "sw1164_${v}_cal$c $f --label '$L' --velocities $v --randomised false --latencies --calibrations $c -- --commit_rad 0.01"
      done
    done > /tmp/res/jobs_a
    for s in $(seq 1164 1179); do
      for v in 0.3 0.5; do
        echo "held42_${s}_$v /tmp/onnx42/policy_$s.onnx --label '$L' --velocities $v --latencies --calibrations -- --commit_rad 0.01"
      done
    done >> /tmp/res/jobs_a
    (cells /tmp/res/jobs_a 12
     tar czf /tmp/res/cells_a.tgz.part -C /tmp/res/cells $(cd /tmp/res/cells && ls -d sw1164_* held42_*) && mv /tmp/res/cells_a.tgz.part /tmp/res/cells_a.tgz) &
    mcort mcort_sel "$R" --seeds 8 --seed_offset 1232 --select 4
    run=$(ls -d /tmp/work/mcort_sel/runs/*/ | head -1)
    p=$(picks mcort_sel)
    tar czf /tmp/res/ck_mcort_sel.tgz.part -C "$run" $(cd "$run" && for s in $p; do echo seed_$s/config.json seed_$s/checkpoints/$(ls seed_$s/checkpoints | sort | tail -1); done) && mv /tmp/res/ck_mcort_sel.tgz.part /tmp/res/ck_mcort_sel.tgz
    export_all "$run" /tmp/res/onnx_mcort_sel $p
    wait
    loops mcort_sel "MARACollisionOrientRandomTarget, $R, pick of 4, exported .onnx" 14
    ;;
  B)
    if [ -e sweep_in/onnx_mcort_sel.tgz ]; then
      tar xzf sweep_in/onnx_mcort_sel.tgz -C /tmp/res
    else
      mkdir -p /tmp/ck && tar xzf sweep_in/ck_mcort_sel.tgz -C /tmp/ck
      export_all /tmp/ck /tmp/res/onnx_mcort_sel $(cd /tmp/ck && ls -d seed_* | sed s/seed_//)
    fi
    mcort plain "cli --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01" --seeds 16 --seed_offset 1296 &
    loops mcort_sel "MARACollisionOrientRandomTarget, $R, pick of 4, exported .onnx" 14
    wait
    ;;
  *) echo "usage: anypose_44.sh A|B" >&2; exit 2 ;;
esac
echo DRIVER_DONE >> /tmp/res/studies.log
