#!/bin/bash
# GPU driver (issue 31, NOTES section 39), round 2 on the development seeds 0-7 (evaluation
# seed 7): the clearance penalty checked along the servo path (train_clearance_path servo,
# 8 points), margins 10 and 20 mm; the same machine as clearance_39.sh's round 1.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
python -m mara_mjx.benchmark robustness --seeds 8 --seed_offset 0 --eval_seed 7 --tasks MARACollision \
  --recipes "default --randomize --train_clearance_penalty 1" \
            "default --randomize --train_clearance_penalty 1 --train_clearance_mm 20" \
  --real_driver --rate_limit true --out /tmp/res/dev2 --work_dir /tmp/work/dev2
echo DRIVER_DONE
