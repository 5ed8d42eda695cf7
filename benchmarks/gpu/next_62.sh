#!/bin/bash
# Issue 31's claim for the learnt policy alone on the Orient tasks, to run once next_61.sh's
# students hold on 1504-1519 (NOTES sections 55-56): on fresh seeds (default 1584-1599,
# OFFSET to change), per task the CLI default (the teacher, itself a fresh check of the
# CLI-default row) and then its students with the candidate recipe (STUDENT, default
# `distill --teacher RUN --imitation_spread 0.05 --reset_noise 0.02`), both judged as the
# task is judged; MARAOrient and MARACollisionOrient at once, sharing GPU 0 (a GPU each
# where the host has two or more); the runs' checkpoints kept (ck_dt_*.tgz).
#   setsid nohup bash benchmarks/gpu/next_62.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 530` in the next calls, back to back, until DRIVER_DONE.
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
export KEEP_LOG=1 STUDENT="${STUDENT:-spread --imitation_spread 0.05 --reset_noise 0.02}"
(export CUDA_VISIBLE_DEVICES=0; bash benchmarks/gpu/distill_51.sh ${OFFSET:-1584} MARAOrient) &
(export CUDA_VISIBLE_DEVICES=$(stream_gpu 1); bash benchmarks/gpu/distill_51.sh ${OFFSET:-1584} MARACollisionOrient) &
wait
echo DRIVER_DONE >> /tmp/res/studies.log
