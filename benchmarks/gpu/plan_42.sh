#!/bin/bash
# GPU driver (issue 32 item 3, issue 31's random-target row; NOTES section 42): the any-pose
# real-arm recipe with the deployed plan, on 16 fresh seeds (1164-1179), one machine:
#  1. the robustness study of MARACollisionOrientRandomTarget `cli --randomize
#     --train_clearance_penalty 1 --plan_steps 16`: 1,000 held-out poses (train driver)
#     and the real driver at 0.3 and 0.5 rad/s, randomised, no rate limit;
#  2. every seed exported to .onnx on the host's CPU (8 at a time; jax2onnx carried);
#  3. the same checkpoints judged without the plan (--plan_steps 0), beside
#  4. the exported files in evaluate's loop (benchmarks/deploy_sweep.py): every seed
#     randomised at both speeds (4 processes), then seed 1164's latency and calibration
#     sweeps (4 processes).
# Each stage leaves its own /tmp/res/*.tgz for poll.sh. Launch with setsid.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
n=mcort_plan
R="cli --randomize --train_clearance_penalty 1 --plan_steps 16"
study() {  # OUT FLAGS...
  local out=$1
  shift
  python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1164 --eval_seed 1000 \
    --tasks MARACollisionOrientRandomTarget --recipes "$R" --real_driver --rate_limit false \
    "$@" --out /tmp/res/$out --work_dir /tmp/work/$n > /tmp/res/$out.log 2>&1
  echo "$out DONE $?" >> /tmp/res/studies.log
  tar czf /tmp/res/$out.tgz.part -C /tmp/res $out $out.log && mv /tmp/res/$out.tgz.part /tmp/res/$out.tgz
}
study $n
run=$(ls -d /tmp/work/$n/runs/*/ | head -1)
keep "$run" /tmp/res/ck_$n.tgz
mkdir -p /tmp/res/onnx
for s in $(seq 1164 1179); do
  JAX_PLATFORMS=cpu python -m mara_mjx.export "$run/seed_$s" /tmp/res/onnx/policy_$s.onnx \
    > /tmp/res/onnx/export_$s.log 2>&1 &
  [ $(( (s - 1163) % 8 )) -eq 0 ] && wait
done
wait
echo "export DONE $(ls /tmp/res/onnx/*.onnx | wc -l)" >> /tmp/res/studies.log
tar czf /tmp/res/onnx.tgz.part -C /tmp/res onnx && mv /tmp/res/onnx.tgz.part /tmp/res/onnx.tgz
study ${n}_noplan --plan_steps 0 &
sweep() {  # NAME FILES... FLAGS...
  python benchmarks/deploy_sweep.py --out /tmp/res/$1 "${@:2}" > /tmp/res/$1.log 2>&1
  echo "$1 DONE $?" >> /tmp/res/studies.log
}
L="MARACollisionOrientRandomTarget, cli --randomize --train_clearance_penalty 1 --plan_steps 16, exported .onnx"
for g in 0 1 2 3; do
  files=$(for i in 0 1 2 3; do echo /tmp/res/onnx/policy_$((1164 + 4 * g + i)).onnx; done)
  sweep rand_$g $files --label "$L" --latencies --calibrations &
done
wait
tar czf /tmp/res/sweeps_rand.tgz.part -C /tmp/res $(cd /tmp/res && ls -d rand_? rand_?.log) && mv /tmp/res/sweeps_rand.tgz.part /tmp/res/sweeps_rand.tgz
f=/tmp/res/onnx/policy_1164.onnx
sweep lat_3 $f --label "$L" --velocities 0.3 --calibrations &
sweep lat_5 $f --label "$L" --velocities 0.5 --calibrations &
sweep cal_3 $f --label "$L" --velocities 0.3 --latencies &
sweep cal_5 $f --label "$L" --velocities 0.5 --latencies &
wait
tar czf /tmp/res/sweeps_1164.tgz.part -C /tmp/res $(cd /tmp/res && ls -d lat_? cal_? lat_?.log cal_?.log) && mv /tmp/res/sweeps_1164.tgz.part /tmp/res/sweeps_1164.tgz
echo DRIVER_DONE >> /tmp/res/studies.log
