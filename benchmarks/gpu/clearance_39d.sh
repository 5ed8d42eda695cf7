#!/bin/bash
# GPU driver (issue 31, NOTES section 39): the claims, seeds 1000-1015, evaluation seed 1000,
# the real driver without the rate limit: `default --randomize --train_clearance_penalty 1`
# at 1x and 2x (1x checkpoints kept), and the same run's baseline `default --randomize`
# (1x) at the same time on the same GPU.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
(python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1000 --eval_seed 1000 \
  --tasks MARACollision --recipes "default --randomize" \
  --real_driver --rate_limit false --out /tmp/res/claims_base --work_dir /tmp/work/claims_base > /tmp/res/claims_base.log 2>&1; echo BASE_DONE >> /tmp/res/claims_base.log) &
python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1000 --eval_seed 1000 \
  --tasks MARACollision --recipes "default --randomize --train_clearance_penalty 1" \
  "default --randomize --train_clearance_penalty 1 --total_timesteps 100000000" \
  --real_driver --rate_limit false --out /tmp/res/claims --work_dir /tmp/work/claims
R=$(ls -d /tmp/work/claims/runs/*/ | awk "{print length, \$0}" | sort -n | head -1 | cut -d" " -f2)
keep "$R" /tmp/res/ck_claims_1x.tgz
wait
echo DRIVER_DONE
