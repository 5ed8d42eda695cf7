#!/bin/bash
# GPU driver (issue 31, NOTES section 39), round 3 on the development seeds 0-7 (evaluation
# seed 7):
# 1) the clearance penalty with the joint step capped in training (the servo's path seen in
#    training, section 38's max_joint_step recipe that learnt paths through the table), w 3,
#    margins 10 and 20 mm, judged on the real driver with the deployed rate limit;
# 2) round 2's `--train_clearance_penalty 1` trainings (checkpoints carried back in
#    gpu_carry/ck_dev2_pen1.tgz) judged on the real driver without the rate limit.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
nvidia-smi -L
J=MARACollision-default-randomize-train_clearance_penalty-1-ff6b5cfa
R=/tmp/work/dev2nrl/runs/$J
mkdir -p $R && tar xzf gpu_carry/ck_dev2_pen1.tgz -C $R
echo "{\"command\": \"python -m mara_mjx.train --env MARACollision --seed 0 --seeds 8 --preset default --randomize --train_clearance_penalty 1 --evaluate false --plots false --tensorboard false --progress false --out $R\", \"timing\": {\"command_s\": 0}}" > /tmp/work/dev2nrl/$J.done
(python -m mara_mjx.benchmark robustness --seeds 8 --seed_offset 0 --eval_seed 7 --tasks MARACollision \
  --recipes "default --randomize --train_clearance_penalty 1" \
  --real_driver --rate_limit false --out /tmp/res/dev2nrl --work_dir /tmp/work/dev2nrl > /tmp/res/dev2nrl.log 2>&1; echo NRL_DONE >> /tmp/res/dev2nrl.log) &
python -m mara_mjx.benchmark robustness --seeds 8 --seed_offset 0 --eval_seed 7 --tasks MARACollision \
  --recipes "default --randomize --max_joint_step 0.03 --gamma 0.98 --train_clearance_penalty 3" \
            "default --randomize --max_joint_step 0.03 --gamma 0.98 --train_clearance_penalty 3 --train_clearance_mm 20" \
  --real_driver --rate_limit true --out /tmp/res/dev3 --work_dir /tmp/work/dev3
wait
echo DRIVER_DONE
