#!/bin/bash
# GPU driver (issue 31, NOTES section 39), development seeds 16-31 (evaluation seed 7), the
# real driver without the rate limit: the clearance penalty alone against it plus
# train_capped_fraction 0.25 and 0.5 (a share of the training envs moving at a servo's
# pace), three studies at once on one GPU.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
R="default --randomize --train_clearance_penalty 1"
study pen1 16 7 "$R" &
study cap25 16 7 "$R --train_capped_fraction 0.25" &
study cap50 16 7 "$R --train_capped_fraction 0.5" &
wait
echo DRIVER_DONE
