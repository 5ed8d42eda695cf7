#!/bin/bash
# GPU driver (issue 35, NOTES section 41): the cold start of the Orient CLI default, every
# compile logged (JAX_LOG_COMPILES), with an empty compilation cache, into /tmp/res/cold.log.
cd "$(dirname "$0")/../.."
. benchmarks/gpu/lib.sh
rm -rf /tmp/jaxcache_cold
( s=$(date +%s.%N)
  JAX_COMPILATION_CACHE_DIR=/tmp/jaxcache_cold JAX_LOG_COMPILES=1 python -m mara_mjx.train \
    --env MARACollisionOrient --seed 1000 --plots false --tensorboard false --progress false \
    --out /tmp/cold_run > /tmp/res/cold.log 2>&1
  echo "rc $? wall $(python -c "import time;print(time.time()-$s)")" >> /tmp/res/cold.log )
