#!/bin/bash
# GPU driver, written for the next device session and NOT YET RUN (issue 32 item 3, issue
# 31's random-target row; the plan at the end of NOTES section 41): MARACollisionOrient-
# RandomTarget's CLI preset with randomised physics and the clearance margin, 64 fresh
# seeds (1100-1163) in one program, kept 1 of each 4 on the real driver with randomised
# physics (selection seed 1001), the 16 picks judged on 1,000 held-out poses (train
# driver) and on the real driver at 0.3 and 0.5 rad/s (evaluation seed 1000), without the
# rate limit. Estimated 20-25 minutes on an H200: alone on one machine. Launch with setsid
# and follow with poll.sh, as select_41.sh.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
n=mcort_sel4
python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1100 --eval_seed 1000 \
  --tasks MARACollisionOrientRandomTarget --recipes "cli --randomize --train_clearance_penalty 1" \
  --real_driver --rate_limit false --select 4 --out /tmp/res/$n --work_dir /tmp/work/$n \
  > /tmp/res/$n.log 2>&1
echo "$n DONE $?" >> /tmp/res/studies.log
tar czf /tmp/res/$n.tgz.part -C /tmp/res $n $n.log && mv /tmp/res/$n.tgz.part /tmp/res/$n.tgz
keep "$(ls -d /tmp/work/$n/runs/*/ | head -1)" /tmp/res/ck_$n.tgz
echo DRIVER_DONE >> /tmp/res/studies.log
