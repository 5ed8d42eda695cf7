#!/bin/bash
# GPU driver (issues 31 and 32; NOTES section 43), written for the next device session (this
# one had no device time): the deployed plan with held commands (`--plan_steps 16
# --commit_rad 0.01`) as recipes on fresh seeds, each study judged again on the same
# checkpoints with --commit_rad 0 (the plan re-asked every step). Two machines:
#   bash commit_43.sh m1   GPU, at once:
#     - s2r_1x / s2r_2x: MARACollision `default --randomize --train_clearance_penalty 1
#       --plan_steps 16 --commit_rad 0.01`, 16 seeds from 1200 at 5e7 and 1e8 env steps, no
#       selection, judged on the real driver (evaluation seed 1000, 1,000 draws per speed);
#     - mcort: MARACollisionOrientRandomTarget `cli --randomize --train_clearance_penalty 1
#       --plan_steps 16 --commit_rad 0.01`, 16 seeds from 1264;
#     then each again with --commit_rad 0 (same --work_dir: judged, not trained), and the
#     mcort seeds exported (.onnx, host CPU) and run in evaluate's loop, 1,000 episodes
#     per speed (the file's commit_rad applied by the loop), 8 processes.
#   bash commit_43.sh m2   GPU: mcort_sel: the same MARACollisionOrientRandomTarget recipe
#     with a pick of 4 (8 picks of 32 candidates from 1232; selection draws seed 1001);
#     CPU beside it: the section-42 file of seed 1164 with latency 0-3 and calibration
#     0-4 mrad, 1,000 episodes per cell, held commands (--commit_rad 0.01), carried in
#     sweep_in/onnx42.tgz.
# Results in /tmp/res/NAME.tgz, checkpoints in /tmp/res/ck_NAME.tgz. Launch with setsid
# and follow with poll.sh.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
pack() {  # NAME: its folder and log, whole or not at all
  tar czf /tmp/res/$1.tgz.part -C /tmp/res $(cd /tmp/res && ls -d $1 $1.log 2>/dev/null) && mv /tmp/res/$1.tgz.part /tmp/res/$1.tgz
}
mcort() {  # NAME WORK RECIPE FLAGS...
  local n=$1 work=$2 recipe=$3
  shift 3
  python -m mara_mjx.benchmark robustness --eval_seed 1000 \
    --tasks MARACollisionOrientRandomTarget --recipes "$recipe" \
    --real_driver --rate_limit false "$@" --out /tmp/res/$n --work_dir /tmp/work/$work \
    > /tmp/res/$n.log 2>&1
  echo "$n DONE $?" >> /tmp/res/studies.log
  pack $n
}
s2r() {  # NAME WORK BUDGET FLAGS...: MARACollision, 16 seeds from 1200, trained once per WORK
  local n=$1 work=$2 budget=$3
  shift 3
  python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1200 --eval_seed 1000 \
    --tasks MARACollision --real_driver --rate_limit false \
    --recipes "default --randomize --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01$budget" \
    "$@" --out /tmp/res/$n --work_dir /tmp/work/$work > /tmp/res/$n.log 2>&1
  echo "$n DONE $?" >> /tmp/res/studies.log
  pack $n
}
sweep() {  # NAME FILES... FLAGS...
  python benchmarks/deploy_sweep.py --out /tmp/res/$1 "${@:2}" > /tmp/res/$1.log 2>&1
  echo "$1 DONE $?" >> /tmp/res/studies.log
}
R="cli --randomize --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01"
L="MARACollisionOrientRandomTarget, $R, exported .onnx"
case $1 in
  m1)
    B=" --total_timesteps 100000000"
    (s2r s2r_1x s2r_1x ""; s2r s2r_1x_nocommit s2r_1x "" --commit_rad 0) &
    (s2r s2r_2x s2r_2x "$B"; s2r s2r_2x_nocommit s2r_2x "$B" --commit_rad 0) &
    mcort mcort mcort "$R" --seeds 16 --seed_offset 1264
    run=$(ls -d /tmp/work/mcort/runs/*/ | head -1)
    keep "$run" /tmp/res/ck_mcort.tgz
    mcort mcort_nocommit mcort "$R" --seeds 16 --seed_offset 1264 --commit_rad 0 &
    mkdir -p /tmp/res/onnx
    for s in $(seq 1264 1279); do
      JAX_PLATFORMS=cpu python -m mara_mjx.export "$run/seed_$s" /tmp/res/onnx/policy_$s.onnx \
        > /tmp/res/onnx/export_$s.log 2>&1 &
      [ $(( (s - 1263) % 8 )) -eq 0 ] && wait
    done
    wait
    tar czf /tmp/res/onnx.tgz.part -C /tmp/res onnx && mv /tmp/res/onnx.tgz.part /tmp/res/onnx.tgz
    for g in 0 1 2 3 4 5 6 7; do
      sweep loop_$g /tmp/res/onnx/policy_$((1264 + 2 * g)).onnx /tmp/res/onnx/policy_$((1265 + 2 * g)).onnx \
        --label "$L" --latencies --calibrations &
    done
    wait
    tar czf /tmp/res/loops.tgz.part -C /tmp/res $(cd /tmp/res && ls -d loop_* ) && mv /tmp/res/loops.tgz.part /tmp/res/loops.tgz
    ;;
  m2)
    mkdir -p /tmp/onnx42 && tar xzf sweep_in/onnx42.tgz -C /tmp/onnx42
    mcort mcort_sel mcort_sel "$R" --seeds 8 --seed_offset 1232 --select 4 &
    f=/tmp/onnx42/policy_1164.onnx
    for v in 0.3 0.5; do
      sweep lat01_$v $f --label "$L" --randomised false --velocities $v --latencies 0 1 --calibrations -- --commit_rad 0.01 &
      sweep lat23_$v $f --label "$L" --randomised false --velocities $v --latencies 2 3 --calibrations -- --commit_rad 0.01 &
      sweep cal01_$v $f --label "$L" --randomised false --velocities $v --latencies --calibrations 0 0.001 -- --commit_rad 0.01 &
      sweep cal24_$v $f --label "$L" --randomised false --velocities $v --latencies --calibrations 0.002 0.004 -- --commit_rad 0.01 &
    done
    wait
    keep "$(ls -d /tmp/work/mcort_sel/runs/*/ | head -1)" /tmp/res/ck_mcort_sel.tgz
    tar czf /tmp/res/sweep_1164.tgz.part -C /tmp/res $(cd /tmp/res && ls -d lat* cal*) && mv /tmp/res/sweep_1164.tgz.part /tmp/res/sweep_1164.tgz
    ;;
  *) echo "usage: commit_43.sh m1|m2" >&2; exit 2 ;;
esac
echo DRIVER_DONE >> /tmp/res/studies.log
