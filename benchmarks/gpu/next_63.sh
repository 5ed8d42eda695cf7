#!/bin/bash
# Issue 31, after section 60 (the Orient tasks' CLI default now deploys the plan's restarts):
#   1. NOISE=1 (default; NOISE=last: after 2; NOISE=0: not at all): the cause-level
#      alternative, `orient_first_noisy_starts` (trained from the paper evaluation's noisy
#      starts, no plan) on seeds 1584-1599, where the CLI default
#      lost 1597 (MARAOrient) and 1588 (MARACollisionOrient), judged as the preset deploys
#      it, without the restarts: does training from those starts remove the fixed points?
#   2. distill_51.sh OFFSET (default 1600, fresh) for TASK: the CLI default (the fresh-seed
#      check of today's preset, judged with its restarts) and then its students with
#      STUDENT (default: section 59's lookahead, K = 2).
# One task per lease (TASK, default MARAOrient; on an H100 MARAOrient's teachers took 147 s
# and its students 818 s, section 62; MARACollisionOrient next: NOISE=last, the students first):
#   TASK=MARAOrient setsid nohup bash benchmarks/gpu/next_63.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `SNAP=/tmp/work/dt_$TASK bash benchmarks/gpu/poll.sh 540` in the next calls, back to
# back, until DRIVER_DONE (SNAP: the students' newest checkpoints come back on every call).
# GUARD=1: after the students, the same students judged again with a 5-mm collision guard
# deployed (forward kinematics and contact distances, no IK: `--collision_guard_mm 5`).
# SEEDS_TTA="16" (or "1 16 32"): last, issue 35's `benchmark tta --parts seeds` on
# MARACollisionOrient's CLI default (1e7 env steps per seed, cold and warm; ~2 min per count).
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
export KEEP_LOG=1
t=${TASK:-MARAOrient}
export STUDENT="${STUDENT:-lookahead --imitation_spread 0.05 --reset_noise 0.02 --imitation_lookahead 2}"
noise() {  # section 64's preset (section 62 ran MARAOrient's as `cli --reset_noise 0.02`)
  robust noise_$t /tmp/work/noise_$t $t orient_first_noisy_starts --seed_offset 1584
  keep "$(ls -dt /tmp/work/noise_$t/runs/$t-orient_first_noisy_starts*/ | head -1)" /tmp/res/ck_noise_$t.tgz
}
[ "${NOISE:-1}" = 1 ] && noise
bash benchmarks/gpu/distill_51.sh ${OFFSET:-1600} $t
if [ "${GUARD:-0}" = 1 ]; then  # the same students judged again with a 5-mm collision guard
  read -ra st <<< "$STUDENT"
  teacher=$(ls -dt /tmp/work/dt_$t/runs/$t-cli-*/ | head -1)
  robust dt_${t}_${st[0]}_guard /tmp/work/dt_$t $t \
    "distill --teacher ${teacher%/}${st[1]:+ ${st[*]:1}}" --seed_offset ${OFFSET:-1600} \
    --collision_guard_mm 5
fi
[ "${NOISE:-1}" = last ] && noise
[ -n "$SEEDS_TTA" ] && tta_seeds $SEEDS_TTA  # issue 35: PPO env steps/s with --seeds N
echo DRIVER_DONE >> /tmp/res/studies.log
