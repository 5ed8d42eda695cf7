#!/bin/bash
# GPU driver (issue 31, NOTES section 41): the sim-to-real recipe with selection. 64 fresh
# seeds (1016-1079) of `default --randomize --train_clearance_penalty 1`, trained in one
# program, kept 1 of each 4 by the real driver with randomised physics on the selection
# draws (seed 1001), the 16 picks judged on evaluation seed 1000, without the rate limit;
# 1x and 2x as two studies at once on one GPU (about 24 minutes on an H200). Launch it
# with setsid (a call's own background jobs end with the call) and follow it with poll.sh.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
R="default --randomize --train_clearance_penalty 1"
study sel4_1x 1016 1000 "$R" --select 4 &
study sel4_2x 1016 1000 "$R --total_timesteps 100000000" --select 4 &
wait
for n in sel4_1x sel4_2x; do tar czf /tmp/res/$n.tgz.part -C /tmp/res $n $n.log && mv /tmp/res/$n.tgz.part /tmp/res/$n.tgz; done
R1=$(ls -d /tmp/work/sel4_1x/runs/*/ | head -1)
keep "$R1" /tmp/res/ck_sel4_1x.tgz
echo DRIVER_DONE >> /tmp/res/studies.log
