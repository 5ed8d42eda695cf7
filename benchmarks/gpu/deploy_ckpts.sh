#!/bin/bash
# GPU driver (issue 32's deploy checks): the CLI defaults of MARA, MARACollision,
# MARACollisionRandomTarget and MARACollisionOrientRandomTarget, 8 seeds from 1000, each
# seed's config and final checkpoint kept in /tmp/res/ck_<task>.tgz for
# benchmarks/deploy_check.py on the CPU.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
mkdir -p /tmp/ck
for t in MARA MARACollision MARACollisionRandomTarget MARACollisionOrientRandomTarget; do
  s=$(date +%s)
  python -m mara_mjx.train --env $t --seed 1000 --seeds 8 --evaluate false --plots false \
    --tensorboard false --progress false --out /tmp/ck/$t > /tmp/res/train_$t.log 2>&1
  echo "$t rc $? $(( $(date +%s) - s )) s"
  keep /tmp/ck/$t /tmp/res/ck_$t.tgz
done
echo STREAM2_DONE
