#!/bin/bash
# Issue 31's rows still short after study 55 (NOTES section 53), three streams sharing one
# GPU (one per GPU where the host has several):
#   S1: MARAOrientRandomTarget with `random_target_orient_plan` (MARACollisionOrientRandomTarget's
#       preset: the plan and its 16 restarts), fresh seeds 1568-1583 (its CLI default
#       `random_target_orient` lost 2 of 16 on 1520-1535: corner poses);
#   S2: MARACollisionOrient's students with the wider exploration floor
#       (`distill --teacher T --log_std_floor -3`), seeds 1504-1519, T the CLI-default run of
#       study 55's rerun (today's guard), carried as sweep_in/teach_mco.tgz (its seeds'
#       config.json and final checkpoint): no teacher retrained. Checkpoints kept;
#   S3: MARAOrient: its CLI default on 1504-1519 with today's guard (its README row is from
#       study 52, before the guard's slide) and that run's students with the same floor.
#   setsid nohup bash benchmarks/gpu/next_60.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 530` in the next calls, back to back, until DRIVER_DONE.
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
export KEEP_LOG=1 STUDENT="floor --log_std_floor -3"
teach=/tmp/work/teach_mco
mkdir -p $teach && tar xzf sweep_in/teach_mco.tgz -C $teach || { echo "teacher FAILED" >> /tmp/res/studies.log; }
(export CUDA_VISIBLE_DEVICES=$(stream_gpu 0)
 robust rtp_MARAOrientRandomTarget /tmp/work/rtp_MAORT MARAOrientRandomTarget random_target_orient_plan --seed_offset 1568) &
(export CUDA_VISIBLE_DEVICES=$(stream_gpu 1)
 robust dt_MARACollisionOrient_floor /tmp/work/dt_MCO MARACollisionOrient "distill --teacher $teach --log_std_floor -3" --seed_offset 1504
 keep "$(ls -dt /tmp/work/dt_MCO/runs/MARACollisionOrient-distill-*/ | head -1)" /tmp/res/ck_dt_MARACollisionOrient_floor.tgz) &
(export CUDA_VISIBLE_DEVICES=$(stream_gpu 2); bash benchmarks/gpu/distill_51.sh 1504 MARAOrient) &
wait
echo DRIVER_DONE >> /tmp/res/studies.log
