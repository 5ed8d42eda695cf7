#!/bin/bash
# Issue 31 (NOTES section 65): one lease of about 20 minutes, one study after another (a
# lease cut short keeps the first ones), each packed as it ends (/tmp/res/NAME.tgz) with
# its runs' checkpoints (ck_NAME.tgz):
#   `orient_first_noisy_starts` (trained from the paper evaluation's noisy starts, no plan)
#      judged as the preset deploys it: fresh seeds 1616-1631 on MARACollisionOrient, then
#      on MARAOrient, then MARACollisionOrient's 1584-1599 (study 62's seed 1588), about
#      200 s each on an H100;
#   then MARACollisionOrientRandomTarget's CLI default on fresh seeds 1616-1631, today's
#      code (the README's row, mcort_clear/, was measured before the guard's last change;
#      about 10 minutes; MCORT_FIRST=1: first).
#   setsid nohup bash benchmarks/gpu/next_65.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 540` in the next calls until DRIVER_DONE.
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
driver_start
one() {  # NAME TASK OFFSET RECIPE: one study of 16 seeds, its checkpoints kept
  local n=$1 t=$2 work=/tmp/work/$1
  robust $n $work $t "$4" --seed_offset $3
  keep "$(ls -dt $work/runs/$t-*/ | head -1)" /tmp/res/ck_$n.tgz
}
${MCORT_FIRST:+one mcort_1616 MARACollisionOrientRandomTarget 1616 cli}
one noise_mco_1616 MARACollisionOrient 1616 orient_first_noisy_starts
one noise_mao_1616 MARAOrient 1616 orient_first_noisy_starts
one noise_mco_1584 MARACollisionOrient 1584 orient_first_noisy_starts
[ -n "$MCORT_FIRST" ] || one mcort_1616 MARACollisionOrientRandomTarget 1616 cli
driver_done
