#!/bin/bash
# GPU driver (issue 31): seeds 1000-1015, evaluation seed 1000.
# 1) MARACollisionOrient's CLI default again, keeping seed 1010's checkpoint (its hold collides);
# 2) the README's sim-to-real recipe (default --randomize, 1x and 2x budget) judged on the real
#    driver with the deployed rate limit (EvalConfig.rate_limit), keeping the 1x checkpoints.
cd "$(dirname "$0")/../.."
export PYTHONUNBUFFERED=1 JAX_DEFAULT_MATMUL_PRECISION=highest JAX_COMPILATION_CACHE_DIR=/tmp/jaxcache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0
nvidia-smi -L
python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1000 --eval_seed 1000 \
  --tasks MARACollisionOrient --recipes cli --out /tmp/res/mco --work_dir /tmp/work/mco
R=$(ls -d /tmp/work/mco/runs/*/ | head -1)
tar czf /tmp/res/mco_ckpts.tgz -C "$R" $(cd "$R" && for s in seed_*; do echo $s/config.json $s/checkpoints/$(ls $s/checkpoints | sort | tail -1); done)
python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1000 --eval_seed 1000 \
  --tasks MARACollision --recipes "default --randomize" "default --randomize --total_timesteps 100000000" \
  --real_driver --rate_limit true --out /tmp/res/s2r_rl --work_dir /tmp/work/s2r
R=$(ls -d /tmp/work/s2r/runs/*/ | awk "{print length, \$0}" | sort -n | head -1 | cut -d" " -f2)
tar czf /tmp/res/s2r_ckpts.tgz -C "$R" $(cd "$R" && for s in seed_*; do echo $s/config.json $s/checkpoints/$(ls $s/checkpoints | sort | tail -1); done)
echo DRIVER_DONE
