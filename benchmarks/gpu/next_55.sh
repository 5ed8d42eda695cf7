#!/bin/bash
# Issue 31's rows that study 52 (NOTES section 52) found short, on ONE H200 (the session's
# only kind; three studies share the GPU, each packed as it ends, most wanted first):
#   A: MARA and MARACollision's CLI defaults with the finish that respects the joint limits
#      (fresh seeds 1552-1567), then MARACollisionOrient's CLI default on 1504-1519 again
#      (study 52's program, its seed 1519 held 22.9 mm off; the guard's slide is deployed
#      only, so this judges it) with its checkpoints kept (ck_fin_MCO.tgz) for
#      benchmarks/episode_trace.py;
#   B, C: MARARandomTarget and MARACollisionRandomTarget with the IK residual, the plan and
#      its 16 restarts (`random_target_orient_plan`) at the default's 5e7 env steps, on
#      1520-1535, against study 52's `random_target` on the same seeds (9 of 16 failed on
#      each): the candidate CLI default for the two tasks.
#   setsid nohup bash benchmarks/gpu/next_55.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 540` in the next calls until DRIVER_DONE.
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
rob() { robust $1 /tmp/work/$1 "$2" "$3" --seed_offset $4; }  # NAME TASKS RECIPE OFFSET
RTP="random_target_orient_plan --total_timesteps 50000000"
(rob fin_1552 "MARA MARACollision" cli 1552
 rob fin_MCO_1504 MARACollisionOrient cli 1504
 keep "$(ls -d /tmp/work/fin_MCO_1504/runs/MARACollisionOrient-cli-*/ | head -1)" /tmp/res/ck_fin_MCO.tgz) &
(rob rtp_MARARandomTarget MARARandomTarget "$RTP" 1520) &
(rob rtp_MARACollisionRandomTarget MARACollisionRandomTarget "$RTP" 1520) &
wait
echo DRIVER_DONE >> /tmp/res/studies.log
