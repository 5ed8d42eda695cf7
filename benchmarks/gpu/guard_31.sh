#!/bin/bash
# GPU driver (issue 31, NOTES section 38): the Orient tasks' CLI default with the deployed
# collision guard (orient_first's collision_guard_mm 5), seeds 1000-1015, evaluation seed 1000.
# 1) MARACollisionOrient: judge the same 16 trainings as claims_31.sh (their checkpoints
#    carried back in, the run folder and .done as the study left them) with --collision_guard_mm 5;
# 2) MARAOrient: train and judge (the preset now carries the guard).
cd "$(dirname "$0")/../.."
export PYTHONUNBUFFERED=1 JAX_DEFAULT_MATMUL_PRECISION=highest JAX_COMPILATION_CACHE_DIR=/tmp/jaxcache JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0
nvidia-smi -L
R=/tmp/work/mco/runs/MARACollisionOrient-cli-291f31e8
mkdir -p $R && tar xzf gpu_carry/mco_ckpts.tgz -C $R
echo "{\"command\": \"python -m mara_mjx.train --env MARACollisionOrient --seed 1000 --seeds 16 --evaluate false --plots false --tensorboard false --progress false --out $R\", \"timing\": {\"command_s\": 162.43087667199998}}" > /tmp/work/mco/MARACollisionOrient-cli-291f31e8.done
python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1000 --eval_seed 1000 \
  --tasks MARACollisionOrient --recipes cli --collision_guard_mm 5 --out /tmp/res/mco_guard --work_dir /tmp/work/mco
python -m mara_mjx.benchmark robustness --seeds 16 --seed_offset 1000 --eval_seed 1000 \
  --tasks MARAOrient --recipes cli --out /tmp/res/mao_guard --work_dir /tmp/work/mao
echo DRIVER_DONE
