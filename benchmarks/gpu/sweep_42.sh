#!/bin/bash
# GPU driver (issue 32 item 3; NOTES section 42): the exported policy_1164.onnx (seed 1164
# of plan_42.sh, `cli --randomize --train_clearance_penalty 1 --plan_steps 16`) in
# evaluate's loop on the real driver, randomised, 1,000 episodes per cell (seed 1000): sensor
# latency 0-3 steps and joint zero offsets 0-4 mrad at 0.3 and 0.5 rad/s, 8 processes
# of 2 cells each. The file is carried in sweep_in/ (untracked). Launch with setsid.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
f=sweep_in/policy_1164.onnx
L="MARACollisionOrientRandomTarget seed 1164, cli --randomize --train_clearance_penalty 1 --plan_steps 16, exported .onnx"
sweep() {  # NAME FLAGS...
  python benchmarks/deploy_sweep.py $f --out /tmp/res/$1 --label "$L" --randomised false "${@:2}" > /tmp/res/$1.log 2>&1
  echo "$1 DONE $?" >> /tmp/res/studies.log
}
for v in 0.3 0.5; do
  sweep lat01_$v --velocities $v --latencies 0 1 --calibrations &
  sweep lat23_$v --velocities $v --latencies 2 3 --calibrations &
  sweep cal01_$v --velocities $v --latencies --calibrations 0 0.001 &
  sweep cal24_$v --velocities $v --latencies --calibrations 0.002 0.004 &
done
wait
tar czf /tmp/res/sweep_1164.tgz.part -C /tmp/res $(cd /tmp/res && ls -d lat* cal*) && mv /tmp/res/sweep_1164.tgz.part /tmp/res/sweep_1164.tgz
echo DRIVER_DONE >> /tmp/res/studies.log
