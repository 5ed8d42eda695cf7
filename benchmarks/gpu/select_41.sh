#!/bin/bash
# GPU driver (issue 31, NOTES section 41): the sim-to-real recipe with selection. 64 fresh
# seeds (1016-1079) of `default --randomize --train_clearance_penalty 1`, trained in one
# program, kept 1 of each 4 by the real driver with randomised physics on the selection
# draws (seed 1001), the 16 picks judged on evaluation seed 1000, without the rate limit;
# 1x and 2x as two studies at once on one GPU. Before them, on the idle GPU, issue 35's
# cold start: the compile log of the Orient CLI default with an empty compilation cache.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -rf /tmp/jaxcache_cold
( s=$(date +%s.%N)
  JAX_COMPILATION_CACHE_DIR=/tmp/jaxcache_cold JAX_LOG_COMPILES=1 python -m mara_mjx.train \
    --env MARACollisionOrient --seed 1000 --plots false --tensorboard false --progress false \
    --out /tmp/cold_run > /tmp/res/cold.log 2>&1
  echo "rc $? wall $(python -c "import time;print(time.time()-$s)")" >> /tmp/res/cold.log )
R="default --randomize --train_clearance_penalty 1"
study sel4_1x 1016 1000 "$R" --select 4 &
study sel4_2x 1016 1000 "$R --total_timesteps 100000000" --select 4 &
wait
for n in sel4_1x sel4_2x; do tar czf /tmp/res/$n.tgz.part -C /tmp/res $n $n.log && mv /tmp/res/$n.tgz.part /tmp/res/$n.tgz; done
R1=$(ls -d /tmp/work/sel4_1x/runs/*/ | head -1)
keep "$R1" /tmp/res/ck_sel4_1x.tgz
echo DRIVER_DONE >> /tmp/res/studies.log
