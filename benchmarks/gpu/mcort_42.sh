#!/bin/bash
# GPU driver (issue 32 item 3, issue 31's random-target row; the plan at the end of NOTES
# section 41): MARACollisionOrientRandomTarget's CLI preset with randomised physics and the
# clearance margin, seeds trained in one program, kept 1 of each 4 on the real driver with
# randomised physics (selection seed 1001; ranked by 5 mm and 2 deg), the picks judged on
# 1,000 held-out poses (train driver) and on the real driver at 0.3 and 0.5 rad/s
# (evaluation seed 1000), without the rate limit.
#   bash mcort_42.sh sel OFFSET   8 judged seeds = 32 candidates from OFFSET (1100, 1132:
#                                 the 16 picks of 1100-1163 in two halves, each well inside
#                                 one machine's 30 minutes)
#   bash mcort_42.sh plain        the plain CLI preset (no randomisation, no margin, no
#                                 selection), 16 seeds from 1100, judged the same way
# Each run's results go to /tmp/res/NAME.tgz and the picks' (or seeds') config and newest
# checkpoint to /tmp/res/ck_NAME.tgz. Launch with setsid and follow with poll.sh.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
run() {  # NAME RECIPE FLAGS...: lib.sh's mcort, then the seeds' checkpoints kept
  mcort "$@"
  keep "$(ls -d /tmp/work/$1/runs/*/ | head -1)" /tmp/res/ck_$1.tgz
}
rm -f /tmp/res/studies.log /tmp/res/sent
case $1 in
  sel) run mcort_sel4_$2 "cli --randomize --train_clearance_penalty 1" --seeds 8 --seed_offset "$2" --select 4 ;;
  plain) run mcort_plain "cli" --seeds 16 --seed_offset 1100 ;;
  *) echo "usage: mcort_42.sh sel OFFSET | plain" >&2; exit 2 ;;
esac
echo DRIVER_DONE >> /tmp/res/studies.log
