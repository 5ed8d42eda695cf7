#!/bin/bash
# GPU driver (issue 31, NOTES section 39): the claims of the capped-share recipe, seeds
# 1000-1015, evaluation seed 1000, real driver without the rate limit; 1x and 2x as two
# studies at once on one GPU (the penalty alone's claims: clearance_39d.sh).
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
R="default --randomize --train_clearance_penalty 1 --train_capped_fraction 0.25"
study cap25_1x 1000 1000 "$R" &
study cap25_2x 1000 1000 "$R --total_timesteps 100000000" &
wait
echo DRIVER_DONE
