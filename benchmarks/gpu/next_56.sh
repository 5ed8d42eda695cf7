#!/bin/bash
# Launched beside next_55.sh in the same lease (one H200) once its first studies had ended:
#   D: MARAOrientRandomTarget's CLI default (`random_target_orient`) on fresh seeds 1520-1535
#      (study 52's was cut off by the lease);
#   E: MARACollisionRandomTarget with `random_target_orient_plan --total_timesteps 5e7` and
#      the deployed 5 mm collision guard (next_55's run without it: 0 of 16 failed, 2% of
#      episodes colliding on average, worst seed 5%), same seeds 1520-1535.
# next_55's DRIVER_DONE is held back until these end (poll.sh stops at the first).
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
(while [ ! -f /tmp/res/n56done ]; do sed -i '/^DRIVER_DONE$/d' /tmp/res/studies.log 2>/dev/null; sleep 3; done) &
rob() { robust $1 /tmp/work/$1 "$2" "$3" --seed_offset $4; }  # NAME TASKS RECIPE OFFSET
(rob rt_MARAOrientRandomTarget MARAOrientRandomTarget cli 1520) &
(rob rtpg_MARACollisionRandomTarget MARACollisionRandomTarget "random_target_orient_plan --total_timesteps 50000000 --collision_guard_mm 5" 1520) &
wait %2 %3
touch /tmp/res/n56done
sleep 4
echo DRIVER_DONE >> /tmp/res/studies.log
