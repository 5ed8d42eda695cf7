#!/bin/bash
# Section 70's lease (issue 35), one H100, GPU otherwise idle (timings), about 20 minutes:
#   1. fused_repeat (lib.sh): the fused step's reset strategies again, both orders, 262,144
#      and 524,288 envs, and profile_step's stages (about 5 minutes);
#   2. cold_59.sh with BEFORE=df3f0d3 (the saved policy's det step in `run`) against this
#      tree (without it): the tta study's cold and warm starts, seeds 1000-1002 (about 14).
# Made here first (ignored by git; carry sweep_in/before):
#   rm -rf sweep_in/before && mkdir -p sweep_in/before
#   git archive df3f0d3 mara_mjx assets | tar -x -C sweep_in/before
# Launch with setsid, follow with poll.sh. QUICK=1: tiny CPU settings.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -f /tmp/res/studies.log /tmp/res/sent
fused_repeat
KEEP_LOG=1 NO_DRIVER_DONE=1 BEFORE=df3f0d3 bash benchmarks/gpu/cold_59.sh
echo DRIVER_DONE >> /tmp/res/studies.log
