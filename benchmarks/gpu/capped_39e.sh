#!/bin/bash
# GPU driver (issue 31, NOTES section 39), development seeds 16-31 (evaluation seed 7), the
# real driver without the rate limit: the clearance penalty alone against it plus
# train_capped_fraction 0.25 and 0.5 (a share of the training envs moving at a servo's
# pace), three studies at once on one GPU.
cd "$(dirname "$0")/../.."
export XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1 JAX_DEFAULT_MATMUL_PRECISION=highest JAX_COMPILATION_CACHE_DIR=/tmp/jaxcache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0
mkdir -p /tmp/res
study() {  # study NAME RECIPE
  python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 16 --eval_seed 7 --tasks MARACollision \
    --recipes "$2" --real_driver --rate_limit false --out /tmp/res/$1 --work_dir /tmp/work/$1 > /tmp/res/$1.log 2>&1
  echo "$1 DONE $?" >> /tmp/res/studies.log
}
study pen1 "default --randomize --train_clearance_penalty 1" &
study cap25 "default --randomize --train_clearance_penalty 1 --train_capped_fraction 0.25" &
study cap50 "default --randomize --train_clearance_penalty 1 --train_capped_fraction 0.5" &
wait
echo DRIVER_DONE
