#!/bin/bash
# Wait up to $1 seconds for the running driver, sending each finished /tmp/res/*.tgz to
# $OUT once (split into 16 MB parts; results before checkpoints: a call brings back about
# 64 MB in all, and what does not fit is left out), and the logs every time; call it again
# within the machine's idle window until studies.log says DRIVER_DONE.
end=$(( $(date +%s) + $1 ))
while :; do
  for f in $(ls /tmp/res/*.tgz 2>/dev/null | grep -v /ck_) $(ls /tmp/res/ck_*.tgz 2>/dev/null); do
    [ -e "$f" ] || continue
    b=$(basename "$f")
    grep -qx "$b" /tmp/res/sent 2>/dev/null || { split -b 16m -d "$f" "$OUT/$b." && echo "$b" >> /tmp/res/sent; }
  done
  cp /tmp/res/cold.log /tmp/res/studies.log "$OUT/" 2>/dev/null
  grep -q DRIVER_DONE /tmp/res/studies.log 2>/dev/null && break
  [ "$(date +%s)" -ge "$end" ] && break
  sleep 10
done
tail -n 3 /tmp/res/*.log 2>/dev/null | tail -n 30
for p in $(ls /tmp/work/*/runs/*/seed_*/progress.csv 2>/dev/null | head -n 1); do echo "$p: $(tail -n 1 "$p" | cut -d, -f1-4)"; done
nvidia-smi --query-gpu=name,utilization.gpu,memory.used --format=csv,noheader
