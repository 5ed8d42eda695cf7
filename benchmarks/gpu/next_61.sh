#!/bin/bash
# Issue 31, the learnt policy alone (NOTES section 54), then issue 35's cold start:
#   1. students of MARAOrient and MARACollisionOrient (seeds 1504-1519, study 60's teachers,
#      MARAOrient's bitwise study 52's: sweep_in/teach_mao_small.tgz and teach_mco_small.tgz, made with
#      benchmarks/strip_teacher.py) with `--imitation_spread 0.05` (env i of N explores at
#      least 0.05 i / (N - 1) rad; the loss keeps the student's own sigma: for study 60's
#      slow closed loop near the target, NOTES section 55) and `--reset_noise 0.02` (the
#      episodes start as the paper's evaluation starts them: for the first steps the
#      students got wrong from noisy starts, section 55): the lost episodes of study 52's
#      students and the 2-4 mm stops of study 60's, both gone?
#      Sharing GPU 0 (a GPU each where the host has two or more); the students'
#      checkpoints come back stripped (ck_sp_TASK.tgz: params only, enough to evaluate).
#   2. `cold_59.sh` with PACKAGES="main before", alone on GPU 0 after the students
#      (timings: nothing else on the host): main now also compiles the reach probe as its
#      own program beside run's (NOTES section 56). Needs sweep_in/before (cold_59.sh's header).
#   setsid nohup bash benchmarks/gpu/next_61.sh > /tmp/res_driver.log 2>&1 < /dev/null & disown
# then `bash benchmarks/gpu/poll.sh 530` in the next calls, back to back, until DRIVER_DONE.
# Carry .whl, SOURCE_COMMIT and sweep_in/{teach_mao_small.tgz,teach_mco_small.tgz,before}
# (a teacher archive not carried: its teachers trained first, the CLI default on 1504).
# TASKS: the students' tasks (default "MARAOrient MARACollisionOrient"); NO_COLD=1: no step 2.
# FLAGS: the students' flags after `distill --teacher RUN` (default below); OFFSET: seeds.
# QUICK=1: the studies' tiny CPU settings, for a check before a GPU call.
# The first run (0f2ea6d, study 61) stopped every student at update ~160: the divergence
# guard read PPO's clip loss, overflowing on the spread's samples and not trained on
# (NOTES section 58; fixed in the commit after).
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
export KEEP_LOG=1
FLAGS=${FLAGS:---imitation_spread 0.05 --reset_noise 0.02}
student() {  # TASK SHORT
  local t=$1 teach=/tmp/work/teach_$2 work=/tmp/work/sp_$1
  if [ -f sweep_in/teach_$2_small.tgz ]; then
    mkdir -p $teach && tar xzf sweep_in/teach_$2_small.tgz -C $teach || { echo "teacher $2 FAILED" >> /tmp/res/studies.log; return; }
  else  # not carried: train them (the CLI default on these seeds; on an H200 bitwise
    # study 52's and 60's, NOTES section 54), judged as the row they are
    robust sp_${t}_cli $work $t cli --seed_offset ${OFFSET:-1504}
    teach=$(ls -d $work/runs/$t-cli-*/ | head -1)
    teach=${teach%/}
  fi
  robust sp_$t $work $t "distill --teacher $teach $FLAGS" --seed_offset ${OFFSET:-1504}
  keep "$(ls -dt $work/runs/$t-distill-*/ | head -1)" $work/ck_full.tgz \
    && python benchmarks/strip_teacher.py $work/ck_full.tgz /tmp/res/ck_sp_$t.tgz.part \
    && mv /tmp/res/ck_sp_$t.tgz.part /tmp/res/ck_sp_$t.tgz
}
i=0
for t in ${TASKS:-MARAOrient MARACollisionOrient}; do
  case $t in MARAOrient) s=mao ;; MARACollisionOrient) s=mco ;; *) echo "unknown task $t" >> /tmp/res/studies.log; continue ;; esac
  (export CUDA_VISIBLE_DEVICES=$(stream_gpu $i); student $t $s) &
  i=$((i + 1))
done
wait
[ -n "$NO_COLD" ] || CUDA_VISIBLE_DEVICES=0 NO_DRIVER_DONE=1 PACKAGES="main before" bash benchmarks/gpu/cold_59.sh
echo DRIVER_DONE >> /tmp/res/studies.log
