#!/bin/bash
# What the GPU drivers share (source it from the repository root):
#   the environment of every run: deterministic precision, no preallocation (several studies
#   share one GPU), a compilation cache in /tmp; /tmp/res, where outputs are collected;
#   keep RUN TGZ [SEEDS...]: each seed's (or the SEEDS') config.json and newest checkpoint
#     of a --seeds run, in TGZ (written whole or not at all);
#   study NAME OFFSET EVAL_SEED RECIPE [FLAGS...]: one MARACollision robustness study of 16
#     seeds, judged on the real driver without the rate limit, into /tmp/res/NAME, its
#     "NAME DONE rc" line appended to /tmp/res/studies.log.
#   mcort NAME RECIPE FLAGS...: one MARACollisionOrientRandomTarget robustness study (real
#     driver without the rate limit, evaluation seed 1000) into /tmp/res/NAME, packed;
#   pack NAME: /tmp/res/NAME and NAME.log into /tmp/res/NAME.tgz (whole or not at all);
#   tta_seeds COUNTS...: issue 35's `benchmark tta --parts seeds` on MARACollisionOrient, packed;
#   robust NAME WORK TASKS RECIPE FLAGS...: one robustness study of 16 seeds (evaluation
#     seed 1000, QUICK=1 its tiny CPU settings) on the training in WORK, packed; judged NAME
#     WORK RECIPE FLAGS...: the same of MARACollisionOrientRandomTarget (starts_49.sh);
#   picks_of NAME: the judged seeds of /tmp/res/NAME's study; export_all RUN OUT SEEDS...:
#     each seed exported to OUT/policy_S.onnx (8 at a time; EXPORT_FLAGS, if set, added);
#     loops NAME LABEL P: every file of /tmp/res/onnx_NAME in evaluate's loop at 0.3 and
#     0.5 rad/s, randomised, P cells at once (moved here from anypose_44.sh);
#   cells JOBS P: run a file of deploy_sweep.py argument lines (NAME ARGS..., each line
#     as bash quotes it: printf '%q ' per argument), P at a time (one
#     1,000-episode cell per line took 4-5 minutes of one CPU core on an H200 host,
#     14 at once beside a training run: onnxruntime on one thread, the simulator on the GPU), each "cell NAME DONE rc" in studies.log.
#   driver_start / driver_done: a driver's studies.log cleared and its DRIVER_DONE written,
#     both skipped under KEEP_LOG=1 (one of several drivers in a row, next_52.sh);
#   stream_gpu I: stream I's GPU (I mod the host's GPUs), for drivers that share one GPU;
#   per_gpu FUNC ARG...: FUNC ARG for each ARG, on GPU i mod N (CUDA_VISIBLE_DEVICES), N at
#     a time (N the GPUs: those of CUDA_VISIBLE_DEVICES where it is set, else the host's;
#     1 without any), waiting for all;
#   the copy of the tree may carry a stale .git (section 45: the session's first HEAD), so the
#     commit it was sent from is read from SOURCE_COMMIT
#     (written here before a run, carried: `echo $(git rev-parse HEAD)$(git status
#     --porcelain --untracked-files=no | grep -q . && echo +dirty) > SOURCE_COMMIT`) into
#     MARA_MJX_GIT_COMMIT, which every artefact's git_commit then records.
export XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1 JAX_DEFAULT_MATMUL_PRECISION=highest JAX_COMPILATION_CACHE_DIR=/tmp/jaxcache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0
mkdir -p /tmp/res
keep() {
  local run=$1 tgz=$2
  shift 2
  local seeds=$(cd "$run" && if [ $# -gt 0 ]; then printf 'seed_%s ' "$@"; else echo seed_*; fi)
  tar czf "$tgz.part" -C "$run" $(cd "$run" && for s in $seeds; do echo $s/config.json $s/checkpoints/$(ls $s/checkpoints | sort | tail -1); done) && mv "$tgz.part" "$tgz"
}
study() {
  local name=$1 offset=$2 eval_seed=$3 recipe=$4
  shift 4
  python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset "$offset" --eval_seed "$eval_seed" \
    --tasks MARACollision --recipes "$recipe" --real_driver --rate_limit false "$@" \
    --out /tmp/res/$name --work_dir /tmp/work/$name > /tmp/res/$name.log 2>&1
  echo "$name DONE $?" >> /tmp/res/studies.log
}
tta_seeds() {  # COUNTS...: issue 35's `tta --parts seeds` on MARACollisionOrient (PPO env
  # steps/s with --seeds N, bits cold vs warm; QUICK=1 its tiny CPU settings), packed
  python -m mara_mjx.benchmark tta --tasks MARACollisionOrient --parts seeds --seeds 1000 \
    --seed_counts "$@" ${QUICK:+--quick} --out /tmp/res/tta_seeds > /tmp/res/tta_seeds.log 2>&1
  echo "tta_seeds DONE $?" >> /tmp/res/studies.log
  pack tta_seeds
}
fused_limit() {  # issue 35: the train-driver env step with kinematics lean and fused against
  # the device's ceilings (`benchmark limit`, MARACollisionOrient; QUICK=1 tiny), packed
  python -m mara_mjx.benchmark limit --tasks MARACollisionOrient --drivers train \
    --kinematics lean fused $([ -n "$QUICK" ] && echo --quick || echo --sizes 65536 262144 1048576) \
    --out /tmp/res/fused_limit > /tmp/res/fused_limit.log 2>&1
  echo "fused_limit DONE $?" >> /tmp/res/studies.log
  pack fused_limit
}
fused_profile() {  # issue 35: where the fused step's time goes (benchmarks/profile_step.py,
  # fused and lean) and `benchmark limit` with the reset strategies select and cond; packed
  # (FP_SIZES: the env counts, default 262144, issue 35's size; about 3 minutes on an H100)
  local q="--sizes ${FP_SIZES:-262144}" o=/tmp/res/fused_profile
  [ -n "$QUICK" ] && q="--sizes 64 --steps 4 --repeats 1"
  mkdir -p $o
  { python benchmarks/profile_step.py --kinematics fused $q --out $o/profile_fused.json
    python benchmarks/profile_step.py --kinematics lean $q --out $o/profile_lean.json
    python -m mara_mjx.benchmark limit --tasks MARACollisionOrient --drivers train \
      --kinematics fused --reset_strategies select cond \
      $([ -n "$QUICK" ] && echo --quick || echo --sizes ${FP_SIZES:-262144}) --out $o
  } > /tmp/res/fused_profile.log 2>&1
  echo "fused_profile DONE $?" >> /tmp/res/studies.log
  pack fused_profile
}
fused_repeat() {  # issue 35: the fused step's reset strategies measured again, in both
  # orders and at two sizes (section 70: profile_step and limit disagreed on which is faster)
  local o=/tmp/res/fused_repeat sizes=${FP_SIZES:-262144 524288} q=""
  [ -n "$QUICK" ] && sizes=64 && q="--steps 4 --repeats 1"
  mkdir -p $o
  { for order in "cond select" "select cond"; do
      python -m mara_mjx.benchmark limit --tasks MARACollisionOrient --drivers train \
        --kinematics fused --reset_strategies $order --sizes $sizes $q --out $o/limit_${order// /_}
    done
    python benchmarks/profile_step.py --kinematics fused --sizes $sizes $q --out $o/profile_fused.json
  } > /tmp/res/fused_repeat.log 2>&1
  echo "fused_repeat DONE $?" >> /tmp/res/studies.log
  pack fused_repeat
}
fused_harness() {  # issue 35: which difference between profile_step's scan and the limit
  # study's loop turns cond's lead into a loss (section 70), 262,144 envs; packed
  local o=/tmp/res/fused_harness q="--sizes ${FP_SIZES:-262144}"
  [ -n "$QUICK" ] && q="--sizes 64 --steps 4 --repeats 1"
  mkdir -p $o
  python benchmarks/profile_step.py --kinematics fused $q --out $o/harness.json --stages \
    batched batched_cond loop loop_cond loop_carried loop_cond_carried > /tmp/res/fused_harness.log 2>&1
  echo "fused_harness DONE $?" >> /tmp/res/studies.log
  pack fused_harness
}
tta_full() {  # issue 35's one-run record: `benchmark tta` with every part (tta, xla_ops,
  # seeds, limit, peers), seeds 1000-1002, MARACollisionOrient; about 15 minutes; packed
  python -m mara_mjx.benchmark tta --seeds 1000 1001 1002 ${QUICK:+--quick --tasks MARA} \
    --out /tmp/res/tta_full > /tmp/res/tta_full.log 2>&1
  echo "tta_full DONE $?" >> /tmp/res/studies.log
  pack tta_full
}
pack() {
  tar czf /tmp/res/$1.tgz.part -C /tmp/res $(cd /tmp/res && ls -d $1 $1.log 2>/dev/null) && mv /tmp/res/$1.tgz.part /tmp/res/$1.tgz
}
mcort() {
  local n=$1 recipe=$2
  shift 2
  python -m mara_mjx.benchmark robustness --eval_seed 1000 \
    --tasks MARACollisionOrientRandomTarget --recipes "$recipe" \
    --real_driver --rate_limit false "$@" --out /tmp/res/$n --work_dir /tmp/work/$n \
    > /tmp/res/$n.log 2>&1
  echo "$n DONE $?" >> /tmp/res/studies.log
  pack $n
}
robust() {  # NAME WORK TASKS RECIPE FLAGS...: one robustness study of 16 seeds (evaluation
  # seed 1000; FLAGS after those, e.g. --seed_offset; QUICK=1: the study's tiny CPU settings)
  # of TASKS (words) on the training in WORK (a second study with the same WORK and train
  # command reuses the first one's runs) into /tmp/res/NAME, its "NAME DONE rc" line in
  # studies.log, packed
  local n=$1 work=$2 tasks=$3 recipe=$4
  shift 4
  python -m mara_mjx.benchmark robustness --eval_seed 1000 --seeds 16 --tasks $tasks \
    --recipes "$recipe" "$@" ${QUICK:+--quick --seeds 2} --out /tmp/res/$n --work_dir $work \
    > /tmp/res/$n.log 2>&1
  echo "$n DONE $?" >> /tmp/res/studies.log
  pack $n
}
judged() {  # NAME WORK RECIPE FLAGS...: robust on MARACollisionOrientRandomTarget
  local n=$1 work=$2 recipe=$3
  shift 3
  robust $n $work MARACollisionOrientRandomTarget "$recipe" "$@"
}
cell() {  # NAME ARGS...: one deploy_sweep.py run into /tmp/res/cells/NAME
  python benchmarks/deploy_sweep.py --out /tmp/res/cells/$1 "${@:2}" > /tmp/res/cells/$1.log 2>&1
  echo "cell $1 DONE $?" >> /tmp/res/studies.log
}
cells() {
  mkdir -p /tmp/res/cells
  export -f cell
  xargs -d '\n' -P "$2" -n 1 bash -c 'eval "cell $1"' _ < "$1" || echo "cells $1 FAILED $?" >> /tmp/res/studies.log
}
picks_of() {  # NAME: the judged seeds of /tmp/res/NAME's study
  python -c "import json,sys; print(*[r['seed'] for r in json.load(open(sys.argv[1]))['records'] if r['kind'] == 'seed'])" /tmp/res/$1/robustness.json
}
export_all() {  # RUN OUT SEEDS...: each seed of RUN exported to OUT/policy_S.onnx, 8 at a time
  local run=$1 out=$2 pids=()
  shift 2
  mkdir -p $out
  for s in "$@"; do  # (its own jobs only: A's CPU cells run on beside them)
    JAX_PLATFORMS=cpu python -m mara_mjx.export "$run/seed_$s" $out/policy_$s.onnx $EXPORT_FLAGS > $out/export_$s.log 2>&1 &
    pids+=($!)
    [ ${#pids[@]} -eq 8 ] && { wait "${pids[@]}"; pids=(); }
  done
  [ ${#pids[@]} -gt 0 ] && wait "${pids[@]}"
  echo "export $(basename $out) DONE $(ls $out/*.onnx | wc -l)" >> /tmp/res/studies.log
  # (EXPORT_ONNX_TGZ=0: the logs only, where the files are too many to bring back)
  tar czf /tmp/res/$(basename $out).tgz.part -C /tmp/res $( [ "${EXPORT_ONNX_TGZ:-1}" = 0 ] && echo --exclude='*.onnx') $(basename $out) && mv /tmp/res/$(basename $out).tgz.part /tmp/res/$(basename $out).tgz
}
loops() {  # NAME LABEL P: every file of /tmp/res/onnx_NAME at both speeds, randomised
  for f in /tmp/res/onnx_$1/policy_*.onnx; do
    s=$(basename $f .onnx); s=${s#policy_}
    for v in 0.3 0.5; do
      printf '%q ' "loop_${1}_${s}_$v" "$f" --label "$2" --velocities $v --latencies --calibrations; echo
    done
  done > /tmp/res/jobs_loop_$1
  cells /tmp/res/jobs_loop_$1 $3
  tar czf /tmp/res/cells_loop_$1.tgz.part -C /tmp/res/cells $(cd /tmp/res/cells && ls -d loop_$1_*) && mv /tmp/res/cells_loop_$1.tgz.part /tmp/res/cells_loop_$1.tgz
}
stream_gpu() {  # I: the GPU of a driver's stream I, I mod the host's GPU count (0 without any),
  # so that streams share GPU 0 on a one-GPU machine and spread over several
  local n=$(nvidia-smi -L 2>/dev/null | wc -l)
  echo $(( $1 % (n > 0 ? n : 1) ))
}
driver_start() { [ -n "$KEEP_LOG" ] || rm -f /tmp/res/studies.log /tmp/res/sent; }
driver_done() { [ -n "$KEEP_LOG" ] || echo DRIVER_DONE >> /tmp/res/studies.log; }
per_gpu() {  # FUNC ARG...
  local f=$1 gpus i=0 a pids=()
  shift
  if [ -n "$CUDA_VISIBLE_DEVICES" ]; then  # a driver given some of the host's GPUs keeps to them
    IFS=, read -ra gpus <<< "$CUDA_VISIBLE_DEVICES"
  else
    gpus=($(seq 0 $(( $(nvidia-smi -L 2>/dev/null | wc -l) - 1 ))))
    [ ${#gpus[@]} -ge 1 ] || gpus=(0)
  fi
  for a in "$@"; do
    (export CUDA_VISIBLE_DEVICES=${gpus[$((i % ${#gpus[@]}))]}; $f "$a") &
    pids+=($!)
    i=$((i + 1))
    [ ${#pids[@]} -eq ${#gpus[@]} ] && { wait "${pids[@]}"; pids=(); }
  done
  wait
}
if [ -f SOURCE_COMMIT ]; then export MARA_MJX_GIT_COMMIT=$(cat SOURCE_COMMIT); fi
