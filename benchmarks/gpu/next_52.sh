#!/bin/bash
# The studies issue 31 still needs, in a row on one multi-GPU host (NOTES section 51):
#   the learnt policy alone by imitation on the four fixed-target tasks (distill_51.sh),
#   then the random-target tasks' CLI defaults (rt_51.sh).
# Seeds 1504-1519 (distill) and 1520-1535 (random targets): fresh, never used before.
#   setsid nohup bash benchmarks/gpu/next_52.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 560` in the next calls until DRIVER_DONE.
cd "$(dirname "$0")/../.."
mkdir -p /tmp/res && rm -f /tmp/res/studies.log /tmp/res/sent
KEEP_LOG=1 bash benchmarks/gpu/distill_51.sh 1504 MARAOrient MARACollisionOrient MARACollision MARA
KEEP_LOG=1 bash benchmarks/gpu/rt_51.sh 1520 MARACollisionRandomTarget MARARandomTarget MARAOrientRandomTarget
echo DRIVER_DONE >> /tmp/res/studies.log
