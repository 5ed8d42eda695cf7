#!/bin/bash
# Issue 31's rows still short after study 55 (NOTES section 53), most wanted first; one
# stream per GPU where the host has several, all sharing GPU 0 on a one-GPU machine:
#   S1: MARAOrientRandomTarget with MARACollisionOrientRandomTarget's preset
#       (`random_target_orient_plan`: the plan and its 16 restarts), fresh seeds 1568-1583
#       (its CLI default `random_target_orient` lost 2 of 16 on 1520-1535: corner poses);
#   S2: MARACollisionOrient's CLI default on 1504-1519 and its students with the wider
#       exploration floor (`distill --teacher RUN --log_std_floor -3`), checkpoints kept
#       (study 52's students lost 2 of 16 seeds, stuck in contact; next_57's were cut off);
#   S3 (only with 3 or more GPUs): the same for MARAOrient (its CLI default on today's
#       guard, and its students; study 52: 3 of 16 students failed).
#   setsid nohup bash benchmarks/gpu/next_58.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 540` in the next calls, back to back, until DRIVER_DONE.
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
export KEEP_LOG=1 STUDENT="floor --log_std_floor -3"
n=$(nvidia-smi -L 2>/dev/null | wc -l)
[ "$n" -ge 1 ] || n=1
gpu() { echo $(( $1 % n )); }  # stream i's GPU
(export CUDA_VISIBLE_DEVICES=$(gpu 0)
 robust rtp_MARAOrientRandomTarget /tmp/work/rtp_MAORT MARAOrientRandomTarget random_target_orient_plan --seed_offset 1568) &
(export CUDA_VISIBLE_DEVICES=$(gpu 1); bash benchmarks/gpu/distill_51.sh 1504 MARACollisionOrient) &
if [ "$n" -ge 3 ]; then
  (export CUDA_VISIBLE_DEVICES=$(gpu 2); bash benchmarks/gpu/distill_51.sh 1504 MARAOrient) &
fi
wait
echo DRIVER_DONE >> /tmp/res/studies.log
