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
# STUDIES (words, in order; default as run for study 65): which of
#   noise_mco noise_mao noise_1584  the three above (study 65)
#   mcort                           MARACollisionOrientRandomTarget's CLI default, 1616-1631
#   plan_mco plan_mao               section 65's candidate default, `orient_first_noisy_starts`
#                                   with the plan's restarts deployed, on fresh seeds 1632-1647
#   distill_mco                     issue 31's last row: MARACollisionOrient's CLI default on
#                                   fresh seeds 1600-1615 and its students with MARAOrient's
#                                   recipe (distill_51.sh, STUDENT as next_63.sh's; about
#                                   1,150 s on an H100; poll with SNAP=/tmp/work/dt_MARACollisionOrient)
#   tta_seeds                       issue 35: `benchmark tta --parts seeds` on MARACollisionOrient,
#                                   16 seeds in one program cold and warm (PPO env steps/s, bits)
#   mcort_fix                       MARACollisionOrientRandomTarget's CLI default on fresh
#                                   1648-1663 with the restarts' last resort (section 68)
#   fused_limit                     issue 35: `benchmark limit --kinematics lean fused` (section 68)
#   fused_profile                   issue 35: where the fused step's time goes, and the reset
#                                   strategies select and cond (section 69; about 3 minutes)
#   fused_harness                   issue 35: profile_step's loop stages, which harness
#                                   difference flips select/cond (section 70; about 3 min)
#   tta_full                        issue 35: `benchmark tta` with every part, peers included
#                                   (section 70; about 15 minutes)
#   (MCORT_FIRST=1, as before: mcort first)
# e.g. the next lease, by value: STUDIES="mcort_fix fused_limit" (section 68 ran
# "mcort tta_seeds plan_mao"; section 67 the first two of "distill_mco plan_mco plan_mao mcort")
plan="orient_first_noisy_starts --plan_steps 16 --plan_starts 16"
default="noise_mco noise_mao noise_1584 mcort"
[ -n "$MCORT_FIRST" ] && default="mcort noise_mco noise_mao noise_1584"
for s in ${STUDIES:-$default}; do
  case $s in
    noise_mco) one noise_mco_1616 MARACollisionOrient 1616 orient_first_noisy_starts ;;
    noise_mao) one noise_mao_1616 MARAOrient 1616 orient_first_noisy_starts ;;
    noise_1584) one noise_mco_1584 MARACollisionOrient 1584 orient_first_noisy_starts ;;
    distill_mco) KEEP_LOG=1 STUDENT="lookahead --imitation_spread 0.05 --reset_noise 0.02 --imitation_lookahead 2" \
      bash benchmarks/gpu/distill_51.sh 1600 MARACollisionOrient ;;
    mcort) one mcort_1616 MARACollisionOrientRandomTarget 1616 cli ;;
    plan_mco) one plan_mco_1632 MARACollisionOrient 1632 "$plan" ;;
    plan_mao) one plan_mao_1632 MARAOrient 1632 "$plan" ;;
    tta_seeds) tta_seeds 16 ;;
    mcort_fix) one mcort_1648 MARACollisionOrientRandomTarget 1648 cli ;;
    fused_limit) fused_limit ;;
    fused_profile) fused_profile ;;
    fused_harness) fused_harness ;;
    tta_full) tta_full ;;
    *) echo "unknown study $s" >> /tmp/res/studies.log ;;
  esac
done
driver_done
