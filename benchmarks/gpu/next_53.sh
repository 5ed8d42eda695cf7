#!/bin/bash
# Issue 31's two open rows on one 4-GPU host, at once (NOTES section 52):
#   GPUs 0 and 1: the any-pose sim-to-real recipe at twice its budget (2.4e8 env steps per
#     seed; "still so when trained for twice its budget"), 8 seeds per GPU (1536-1543,
#     1544-1551, merged afterwards into one 16-seed row), judged as starts_49.sh's KIND R:
#     1,000 held-out poses on the train driver and 1,000 randomised draws per speed on the
#     real driver; then one random-target CLI default each (rt_51.sh, seeds 1520-1535);
#   GPUs 2 and 3: the learnt policy alone by imitation (distill_51.sh, seeds 1504-1519),
#     two fixed-target tasks per GPU, the Orient tasks first.
#   setsid nohup bash benchmarks/gpu/next_53.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 540` in the next calls until DRIVER_DONE.
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
Q=()
[ -n "$QUICK" ] && Q=(--quick --seeds 2)
R2="cli --randomize --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01 --total_timesteps 240000000"
r2() {  # NAME OFFSET
  judged $1 /tmp/work/$1 "$R2" --seed_offset $2 --seeds 8 --real_driver --rate_limit false "${Q[@]}"
}
export KEEP_LOG=1
(export CUDA_VISIBLE_DEVICES=0; r2 r2a 1536; bash benchmarks/gpu/rt_51.sh 1520 MARACollisionRandomTarget) &
(export CUDA_VISIBLE_DEVICES=1; r2 r2b 1544; bash benchmarks/gpu/rt_51.sh 1520 MARARandomTarget) &
(export CUDA_VISIBLE_DEVICES=2; bash benchmarks/gpu/distill_51.sh 1504 MARAOrient MARACollision) &
(export CUDA_VISIBLE_DEVICES=3; bash benchmarks/gpu/distill_51.sh 1504 MARACollisionOrient MARA) &
wait
echo DRIVER_DONE >> /tmp/res/studies.log
