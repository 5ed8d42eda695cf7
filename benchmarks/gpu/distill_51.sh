#!/bin/bash
# GPU driver (issue 31, "the learnt policy alone"; NOTES section 51): per fixed-target task,
# 16 fresh seeds of the task's CLI default (the teacher, itself judged: a fresh check of
# the CLI-default rows) and then 16 students of `--preset distill --teacher <that run>`
# (student seed s learns from teacher seed s), each judged as the task is judged (the
# paper's evaluation and the hold to the horizon, evaluation seed 1000); with DEFAULT=1
# also `--preset default` on the same seeds (the learnt policy by reward, the README's row
# on seeds 1000-1015). One task per GPU (CUDA_VISIBLE_DEVICES), the tasks beyond the GPUs' count queued.
#   bash benchmarks/gpu/distill_51.sh OFFSET TASK...
#   e.g. bash benchmarks/gpu/distill_51.sh 1504 MARAOrient MARACollisionOrient MARACollision MARA
# Several drivers in a row: KEEP_LOG=1 on each, then `echo DRIVER_DONE >> /tmp/res/studies.log`.
# QUICK=1: the study's tiny CPU settings (--quick), for a check before a GPU call.
# STUDENT="NAME FLAGS...": the students' study NAME with FLAGS after `distill --teacher RUN`
# (default "distill": none).
# Every study's run checkpoints are kept, /tmp/res/ck_dt_<TASK>_<study>.tgz (the seeds'
# config.json and newest checkpoint: the failing seeds' evidence).
# Launch with setsid, follow with poll.sh in the NEXT call. Results: each study's folder
# /tmp/res/dt_<TASK>_<study> and its log, packed as it ends (.tgz).
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
driver_start
offset=$1
shift
one() {  # TASK: teacher study, student study, default study, each packed as it ends
  local t=$1 work=/tmp/work/dt_$1 teacher
  study() { robust dt_${t}_$1 $work $t "$2" --seed_offset $offset; }  # NAME RECIPE
  local student
  read -ra student <<< "${STUDENT:-distill}"
  study cli cli
  teacher=$(ls -dt $work/runs/$t-cli-*/ | head -1)  # the newest: this study's
  keep "$teacher" /tmp/res/ck_dt_${t}_cli.tgz
  study ${student[0]} "distill --teacher ${teacher%/}${student[1]:+ ${student[*]:1}}"
  # the student run this study just trained: the newest distill folder (a work folder
  # may hold an earlier study's students of the same teacher)
  keep "$(ls -dt $work/runs/$t-distill-*/ | head -1)" /tmp/res/ck_dt_${t}_${student[0]}.tgz
  [ -n "$DEFAULT" ] && study default default
}
per_gpu one "$@"
driver_done
