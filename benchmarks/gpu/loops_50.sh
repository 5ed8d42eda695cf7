#!/bin/bash
# GPU host driver (issue 32 item 3; NOTES section 50): the exported files of section 49's
# trainings (MARACollisionOrientRandomTarget, 16 restarts; no pick) in evaluate's loop on
# the real driver with randomised physics, 1,000 held-out poses and draws per cell
# (benchmarks/deploy_sweep.py, evaluation seed 1000), one cell per CPU core, the simulator
# on the GPUs (cell i on GPU i mod N):
#   the recipe `cli --randomize --train_clearance_penalty 1 --plan_steps 16 --commit_rad
#     0.01`, seeds 1456-1471, at 0.3 and 0.5 rad/s, less the cells already run on the
#     project's CPU (SKIP, "SEED_SPEED" words);
#   the plain recipe (the same without --randomize), seeds 1472-1487, at both speeds;
#   the sweep: seeds SWEEP's files at both speeds with the sensor latency fixed at 0-3 steps
#     and the joint zero offsets drawn within 0-4 mrad (--randomised false: the randomised
#     cell is the one above).
# Needs sweep_in/ck50.tgz (carry "sweep_in", excluded from git): rec_c/seed_S and
# plain_c/seed_S, each config.json and the final checkpoint's policy arrays (params/,
# obs_stats/ and the metadata; the env and optimiser state dropped, which neither export
# nor evaluate reads). Launch with setsid, follow with poll.sh in the NEXT call:
#   SKIP="1466_0.5 1466_0.3 1456_0.5 1456_0.3 1460_0.5" SWEEP="1456 1466" P=56 \
#     bash benchmarks/gpu/loops_50.sh
# Results: /tmp/res/onnx_{rec,plain}.tgz (export logs), /tmp/res/cellpack_*.tgz (finished
# cells, packed by poll.sh as they end; poll.sh packs them whenever cells/ exists).
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
mkdir -p /tmp/ck50 /tmp/res/cells && tar xzf sweep_in/ck50.tgz -C /tmp/ck50
EXPORT_ONNX_TGZ=0
P=${P:-14}
seeds_of() { (cd /tmp/ck50/$1 && ls -d seed_* | sed 's/seed_//'); }
# export: P at a time, both trainings (export_all waits for its own 8 at a time: run both)
export_all /tmp/ck50/rec_c /tmp/res/onnx_rec $(seeds_of rec_c) &
export_all /tmp/ck50/plain_c /tmp/res/onnx_plain $(seeds_of plain_c) &
wait
R="MARACollisionOrientRandomTarget, cli --randomize --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01 (16 restarts, no pick), exported .onnx"
PL="MARACollisionOrientRandomTarget, cli --train_clearance_penalty 1 --plan_steps 16 --commit_rad 0.01 (plain: no --randomize in training; 16 restarts, no pick), exported .onnx"
n=$(nvidia-smi -L | wc -l)
{
  for s in ${SWEEP:-}; do  # the sweeps first: the longest cells (latency 3) start early
    f=/tmp/res/onnx_rec/policy_$s.onnx
    for v in 0.3 0.5; do
      for k in 3 2 1 0; do
        printf '%q ' "sw_${s}_${v}_lat$k" $f --label "$R" --velocities $v --randomised false --latencies $k --calibrations; echo
      done
      for c in 0.004 0.002 0.001 0; do
        printf '%q ' "sw_${s}_${v}_cal$c" $f --label "$R" --velocities $v --randomised false --latencies --calibrations $c; echo
      done
    done
  done
  for s in $(seeds_of rec_c); do
    for v in 0.3 0.5; do
      [[ " ${SKIP:-} " == *" ${s}_$v "* ]] && continue
      printf '%q ' "rec_${s}_$v" /tmp/res/onnx_rec/policy_$s.onnx --label "$R" --velocities $v --latencies --calibrations; echo
    done
  done
  for s in $(seeds_of plain_c); do
    for v in 0.3 0.5; do
      printf '%q ' "plain_${s}_$v" /tmp/res/onnx_plain/policy_$s.onnx --label "$PL" --velocities $v --latencies --calibrations; echo
    done
  done
} | awk -v n=$n '{print "CUDA_VISIBLE_DEVICES=" (NR - 1) % n, $0}' > /tmp/res/jobs_50
echo "jobs $(wc -l < /tmp/res/jobs_50)" >> /tmp/res/studies.log
cellg() { local g=$1; shift; env "$g" bash -c '. benchmarks/gpu/lib.sh; cell "$@"' _ "$@"; }
export -f cellg
xargs -d '\n' -P "$P" -n 1 bash -c 'eval "cellg $1"' _ < /tmp/res/jobs_50 || echo "cells FAILED $?" >> /tmp/res/studies.log
echo DRIVER_DONE >> /tmp/res/studies.log
