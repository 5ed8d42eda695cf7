#!/bin/bash
# Section 71's plan for the next lease (issue 35), one H100, GPU otherwise idle (timings),
# about 33 minutes, each part packed as it ends:
#   0. backend_overlap.py --repeat 3: would the backend's start beside the imports save
#      anything on a GPU host (under a minute)?
#   1. fused_harness (lib.sh): profile_step's loop stages, which harness difference turns
#      cond's lead into a loss (section 70; about 3 minutes);
#   2. cold_59.sh with PACKAGES="main cuts": this tree against it with the two trace_cuts
#      patches (benchmarks/archive/trace_cuts/: fewer traced operations, the same
#      arithmetic), the tta study's cold and warm starts, seeds 1000-1002 (about 14): do
#      the patches keep the training hashes on the GPU (cold70's: 370df333..., 89d61be6...,
#      29f377ca...), and what do they take off the cold start?
#   3. tta_full (lib.sh): `benchmark tta` with every part, the peers included (about 15).
# Made here first (ignored by git; carry sweep_in/cuts):
#   rm -rf sweep_in/cuts && mkdir -p sweep_in/cuts
#   git archive HEAD mara_mjx assets | tar -x -C sweep_in/cuts
#   (cd sweep_in/cuts && for p in ../../benchmarks/archive/trace_cuts/*.diff; do patch -p1 < $p; done)
# Launch with setsid, follow with poll.sh. QUICK=1: tiny CPU settings.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
mkdir -p /tmp/res/backend_overlap
python benchmarks/backend_overlap.py --repeat 3 --json /tmp/res/backend_overlap/overlap.jsonl \
  > /tmp/res/backend_overlap.log 2>&1
echo "backend_overlap DONE $?" >> /tmp/res/studies.log
pack backend_overlap
fused_harness
KEEP_LOG=1 NO_DRIVER_DONE=1 PACKAGES="main cuts" bash benchmarks/gpu/cold_59.sh
tta_full
echo DRIVER_DONE >> /tmp/res/studies.log
