#!/bin/bash
# Issue 31's rows that study 52 (NOTES section 52) found short, on one 4-GPU host:
#   GPU 0: MARA and MARACollision's CLI defaults with the finish that respects the joint
#     limits (fresh seeds 1552-1567), then MARACollisionOrient's CLI default on 1504-1519
#     again (the same program as study 52's: its failing seed 1519 kept) and its students
#     with a wider exploration floor (STUDENT, below);
#   GPU 1: the same for MARAOrient (1504-1519), then MARAOrientRandomTarget's CLI default
#     (1520-1535; study 52's was cut off by the lease);
#   GPUs 2 and 3: MARARandomTarget and MARACollisionRandomTarget with
#     MARACollisionOrientRandomTarget's CLI preset (`random_target_orient_plan`: the IK
#     residual, the plan and its restarts) on 1520-1535, against study 52's `random_target`
#     on the same seeds (9 of 16 failed on each).
# STUDENT: `--log_std_floor -3` (sigma >= 0.05 rad where distill learns it down to 0.01):
# rollouts that wander wider around the teacher's path, so the student is taught the way
# back from more states (DART's argument; study 52's failing students stuck off the path).
#   setsid nohup bash benchmarks/gpu/next_54.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 540` in the next calls until DRIVER_DONE.
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
export KEEP_LOG=1 STUDENT="floor --log_std_floor -3"
rob() { robust $1 /tmp/work/$1 "$2" "$3" --seed_offset $4; }  # NAME TASKS RECIPE OFFSET
(export CUDA_VISIBLE_DEVICES=0; rob fin_1552 "MARA MARACollision" cli 1552
 bash benchmarks/gpu/distill_51.sh 1504 MARACollisionOrient) &
(export CUDA_VISIBLE_DEVICES=1; bash benchmarks/gpu/distill_51.sh 1504 MARAOrient
 rob rt_MARAOrientRandomTarget MARAOrientRandomTarget cli 1520) &
(export CUDA_VISIBLE_DEVICES=2; rob rtp_MARARandomTarget MARARandomTarget random_target_orient_plan 1520) &
(export CUDA_VISIBLE_DEVICES=3; rob rtp_MARACollisionRandomTarget MARACollisionRandomTarget random_target_orient_plan 1520) &
wait
echo DRIVER_DONE >> /tmp/res/studies.log
