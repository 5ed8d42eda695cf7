#!/bin/bash
# Issue 31 on ONE H200 (next_55.sh's lease ended before its MARACollisionOrient study came
# back; next_56.sh never started). Three streams share the GPU, each study packed as it ends:
#   S1: MARACollisionOrient's CLI default on 1504-1519 again (study 52's seed 1519 held one
#       episode 22.9 mm off; the guard's slide is deployed only, so this judges it), its
#       checkpoints kept, then its 16 students with the wider exploration floor
#       (`distill --teacher RUN --log_std_floor -3`, NOTES section 52), checkpoints kept;
#   S2: MARAOrientRandomTarget's CLI default (`random_target_orient`) on fresh seeds
#       1520-1535 (study 52's was cut off by its lease);
#   S3: MARACollisionRandomTarget with `random_target_orient_plan --total_timesteps 5e7`
#       and the deployed 5 mm collision guard, seeds 1520-1535 (next_55's run without the
#       guard: 0 of 16 failed, 2% of episodes colliding on average, worst seed 5%).
#   setsid nohup bash benchmarks/gpu/next_57.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 540` in the next calls, back to back, until DRIVER_DONE.
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
export KEEP_LOG=1
rob() { robust $1 /tmp/work/$1 "$2" "$3" --seed_offset $4; }  # NAME TASKS RECIPE OFFSET
(STUDENT="floor --log_std_floor -3" bash benchmarks/gpu/distill_51.sh 1504 MARACollisionOrient) &
(rob rt_MARAOrientRandomTarget MARAOrientRandomTarget cli 1520) &
(rob rtpg_MARACollisionRandomTarget MARACollisionRandomTarget "random_target_orient_plan --total_timesteps 50000000 --collision_guard_mm 5" 1520) &
wait
echo DRIVER_DONE >> /tmp/res/studies.log
