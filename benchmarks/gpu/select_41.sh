#!/bin/bash
# GPU driver (issue 31, NOTES section 41): the sim-to-real recipe with selection. 64 fresh
# seeds (1016-1079) of `default --randomize --train_clearance_penalty 1`, trained in one
# program, kept 1 of each 4 by the real driver with randomised physics on the selection
# draws (seed 1001), the 16 picks judged on evaluation seed 1000, without the rate limit;
# `select_41.sh 1x` or `select_41.sh 2x`, one per machine: at once on one H200 the two
# would pass the machine's 30 minutes (each seed trained at 56.5 k env steps/s while both
# ran). Launch it with setsid (a call's own background jobs end with the call) and follow
# it with poll.sh.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent  # poll.sh stops at DRIVER_DONE; a warm machine keeps the last
R="default --randomize --train_clearance_penalty 1"
case $1 in
  1x) study sel4_1x 1016 1000 "$R" --select 4 ;;
  2x) study sel4_2x 1016 1000 "$R --total_timesteps 100000000" --select 4 ;;
  *) echo "usage: select_41.sh 1x|2x"; exit 2 ;;
esac
n=sel4_$1
tar czf /tmp/res/$n.tgz.part -C /tmp/res $n $n.log && mv /tmp/res/$n.tgz.part /tmp/res/$n.tgz
keep "$(ls -d /tmp/work/$n/runs/*/ | head -1)" /tmp/res/ck_$n.tgz
echo DRIVER_DONE >> /tmp/res/studies.log
