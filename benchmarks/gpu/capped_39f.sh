#!/bin/bash
# GPU driver (issue 31, NOTES section 39): the claims of the capped-share recipe, seeds
# 1000-1015, evaluation seed 1000, real driver without the rate limit; 1x and 2x as two
# studies at once on one GPU (the penalty alone's claims: clearance_39d.sh).
cd "$(dirname "$0")/../.."
export XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1 JAX_DEFAULT_MATMUL_PRECISION=highest JAX_COMPILATION_CACHE_DIR=/tmp/jaxcache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0
mkdir -p /tmp/res
R="default --randomize --train_clearance_penalty 1 --train_capped_fraction 0.25"
study() {  # study NAME RECIPE
  python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1000 --eval_seed 1000 --tasks MARACollision \
    --recipes "$2" --real_driver --rate_limit false --out /tmp/res/$1 --work_dir /tmp/work/$1 > /tmp/res/$1.log 2>&1
  echo "$1 DONE $?" >> /tmp/res/studies.log
}
study cap25_1x "$R" &
study cap25_2x "$R --total_timesteps 100000000" &
wait
echo DRIVER_DONE
