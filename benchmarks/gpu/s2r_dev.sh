#!/bin/bash
# GPU driver: issue 31 sim-to-real development on tuning seeds 0-7 (not for claims).
cd "$(dirname "$0")/../.."
export PYTHONUNBUFFERED=1 JAX_DEFAULT_MATMUL_PRECISION=highest JAX_COMPILATION_CACHE_DIR=/tmp/jaxcache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0
nvidia-smi -L
python -m mara_mjx.benchmark robustness --seeds 8 --seed_offset 0 --eval_seed 7 --tasks MARACollision \
  --recipes "default --randomize --max_joint_step 0.03 --gamma 0.98" \
            "default --randomize --max_joint_step 0.015 --gamma 0.99" \
            "default --randomize --max_joint_step 0.03 --gamma 0.98 --hidden_obs 9 10 11" \
  --real_driver --rate_limit true --out /tmp/res/dev --work_dir /tmp/work/dev
echo DRIVER_DONE $?
