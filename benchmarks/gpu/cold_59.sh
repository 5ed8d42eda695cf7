#!/bin/bash
# Issue 35's cold start on the GPU, in one run (NOTES sections 53 and 58): `python -m
# mara_mjx.benchmark tta --parts tta` (MARACollisionOrient, its CLI default; seeds
# 1000-1002, each cold with an empty compilation cache and then warm) for two packages,
# alternating (ROUNDS, default 1):
#   before   sweep_in/before: the code at BEFORE (default ac8d6a3~1: `update` traced twice,
#            the reach probe inside run, the guard's nine clearances nine copies; section 70:
#            df3f0d3, the saved policy's det step still in run);
#   main     this tree (all three changed; every one bitwise the same training: study 61,
#            results/time_to_accuracy/cold61/).
# Made here (ignored by git; carry sweep_in/before):
#   rm -rf sweep_in/before && mkdir -p sweep_in/before
#   git archive ${BEFORE:-ac8d6a3~1} mara_mjx assets | tar -x -C sweep_in/before
# (Study 61 also ran a package `guardmap`, main with the guard's lax.map as a patch, since
# landed: git log -- mara_mjx/envs/clearance.py.)
# Run it alone on the GPU (timings). Launch with setsid, follow with poll.sh.
# QUICK=1: the study's tiny CPU settings. PACKAGES: which of the two (default both).
# SEEDS: the tta seeds (default "1000 1001 1002").
# NO_DRIVER_DONE=1: leave DRIVER_DONE to the caller (one of several drivers in a row).
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
[ -n "$KEEP_LOG" ] || rm -f /tmp/res/studies.log /tmp/res/sent
site=${SITE-/tmp/site}
one() {  # NAME PACKAGE_ROOT COMMIT (run from it: `python -m` puts the working folder first on
  # sys.path, and the train commands the study launches inherit both; COMMIT is what the
  # artefacts record as their git commit)
  rm -rf /tmp/work/$1 && mkdir -p /tmp/work/$1
  (cd $2 && MARA_MJX_GIT_COMMIT=$3 PYTHONPATH=$site:$2 python -m mara_mjx.benchmark tta --parts tta \
    --seeds ${SEEDS:-1000 1001 1002} ${QUICK:+--quick} --out /tmp/res/$1 --work_dir /tmp/work/$1 > /tmp/res/$1.log 2>&1)
  echo "$1 DONE $? ($(df -h /tmp | tail -1 | awk '{print $4}') free on /tmp)" >> /tmp/res/studies.log
  [ -s /tmp/res/$1.log ] || echo "$1: no log (cd $2 or the log's creation failed: res_driver.log says)" >> /tmp/res/studies.log
  # every package's runs hashed by this tree's code, the env state's metrics left out
  # (`state_hash(training_only=True)`, NOTES section 56; the before package predates it)
  PYTHONPATH=$site:$PWD python -c "import sys; from pathlib import Path; from mara_mjx.bench.train_command import state_hash as h
for d in sorted(Path(sys.argv[1]).glob('*/runs/*/')): print(d.name, h(d), h(d, training_only=True))" /tmp/work/$1 > /tmp/res/$1/training_hashes.txt 2>&1
  rm -rf /tmp/work/$1/*/cache-seed*  # (the caches: gigabytes on a GPU)
  pack $1
}
packages=${PACKAGES:-before main}  # (a subset, e.g. PACKAGES=main; or another sweep_in/NAME,
# e.g. PACKAGES="main cuts": this tree with NOTES 71's trace_cuts patches, section 71 says how)
for d in $packages; do
  [ $d = main ] && continue
  [ -d sweep_in/$d/mara_mjx ] || { echo "no sweep_in/$d/mara_mjx" >> /tmp/res/studies.log; [ -n "$NO_DRIVER_DONE" ] || echo DRIVER_DONE >> /tmp/res/studies.log; exit 1; }
done
here=${MARA_MJX_GIT_COMMIT:-unknown}
for round in $(seq 1 ${ROUNDS:-1}); do  # one round: 18 train commands, about 14 min on an H100
  for d in $packages; do
    case $d in
      before) one tta_before_$round $PWD/sweep_in/before ${BEFORE:-ac8d6a3~1} ;;
      main) one tta_main_$round $PWD $here ;;
      *) one tta_${d}_$round $PWD/sweep_in/$d "$here+$d" ;;  # sweep_in/NAME: a patched tree
    esac
  done
done
[ -n "$NO_DRIVER_DONE" ] || echo DRIVER_DONE >> /tmp/res/studies.log
