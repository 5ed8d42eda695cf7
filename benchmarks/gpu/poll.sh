#!/bin/bash
# Wait up to $1 seconds for the running driver, sending the /tmp/res/*.tgz finished since
# the last call to $OUT once, as one tar per call (results before checkpoints; split into
# 16 MB parts: a call brings back at most 8 files and about 64 MB, so what does not fit
# waits for the next call), and the logs every time; call it again within the machine's
# idle window until studies.log says DRIVER_DONE. (Section 45 lost a call's worth of
# files to the 8-file limit when each .tgz went on its own.) Cells of deploy_sweep.py
# (lib.sh's cells) are packed as they finish (cellpack_*.tgz), so a machine taken back
# mid-run loses only the running ones.
end=$(( $(date +%s) + $1 ))
packcells() {  # the cells finished since the last pack (cells/NAME and its log) as one .tgz
  [ -d /tmp/res/cells ] || return 0
  local done=() n
  for n in $(grep -o '^cell [^ ]* DONE' /tmp/res/studies.log 2>/dev/null | cut -d' ' -f2); do
    grep -qx "$n" /tmp/res/packed 2>/dev/null || done+=("$n")
  done
  [ ${#done[@]} -gt 0 ] || return 0
  local t=/tmp/res/cellpack_$(date +%s).tgz
  tar czf "$t.part" -C /tmp/res/cells $(for n in "${done[@]}"; do (cd /tmp/res/cells && ls -d "$n" "$n.log" 2>/dev/null); done) \
    && mv "$t.part" "$t" && printf '%s\n' "${done[@]}" >> /tmp/res/packed
}
send() {  # the finished .tgz not yet sent, up to about 48 MB, as one tar in parts
  local new=() size=0 f s
  for f in $(ls /tmp/res/*.tgz 2>/dev/null | grep -v /ck_) $(ls /tmp/res/ck_*.tgz 2>/dev/null); do
    grep -qx "$(basename "$f")" /tmp/res/sent 2>/dev/null && continue
    s=$(stat -c %s "$f")
    [ ${#new[@]} -gt 0 ] && [ $((size + s)) -gt 50000000 ] && break
    new+=("$(basename "$f")"); size=$((size + s))
  done
  [ ${#new[@]} -gt 0 ] || return 0
  local tar=/tmp/res/batch_$(date +%s).tar
  tar cf "$tar" -C /tmp/res "${new[@]}" && split -b 16m -d "$tar" "$OUT/$(basename "$tar")." \
    && printf '%s\n' "${new[@]}" >> /tmp/res/sent
  rm -f "$tar"
}
while :; do
  grep -q DRIVER_DONE /tmp/res/studies.log 2>/dev/null && done=1
  [ "$(date +%s)" -ge "$end" ] && done=1
  [ -n "$done" ] && break
  sleep 10
done
packcells
send
# SNAP="WORK..." (work folders, e.g. /tmp/work/dt_MARAOrient): each run folder there with
# only the newest checkpoint all its seeds have (what `--resume` needs), as
# $OUT/snap_<work>.tgz.NN (15-MB parts), every call the files allow (at most 8 files, about
# 64 MB, with this call's batch and logs): a machine taken back mid-training (section 60
# lost 800 s of students so) leaves the last one, which the robustness study resumes
# (`continue_argv`) from the same work folder on the next machine
cp /tmp/res/cold.log /tmp/res/studies.log "$OUT/" 2>/dev/null
tail -c 200000 /tmp/res_driver.log > "$OUT/res_driver.log" 2>/dev/null  # the driver's own errors (study 61 lost two studies' reason)
for w in $SNAP; do
  [ -d "$w/runs" ] || continue
  n=$(basename "$w"); t="/tmp/snap_$n.tar"
  rm -f "$t" "$t.gz"
  (cd "$(dirname "$w")" || exit 1
   tar cf "$t" --warning=no-file-changed --exclude='*/checkpoints/*' "$n"
   [ $? -le 1 ] || exit 1  # 1: a file changed while read (a log being written)
   for r in "$n"/runs/*/; do
     k=$(ls -d "$r"seed_*/checkpoints 2>/dev/null | wc -l)
     [ "$k" -gt 0 ] || continue
     last=$(for c in "$r"seed_*/checkpoints; do ls "$c" | grep -E '^ckpt_[0-9]+\.npz$'; done \
       | sort | uniq -c | awk -v k="$k" '$1 == k {print $2}' | tail -n 1)
     [ -n "$last" ] && tar rf "$t" "$r"seed_*/checkpoints/"$last"
   done
   gzip "$t") || { echo "snap $n failed"; continue; }
  files=$(ls "$OUT" | wc -l); bytes=$(du -sb "$OUT" | cut -f1); size=$(stat -c %s "$t.gz")
  parts=$(( (size + 15728639) / 15728640 ))
  if [ $((files + parts)) -le 8 ] && [ $((bytes + size)) -le 62000000 ]; then
    split -b 15m -d "$t.gz" "$OUT/snap_$n.tgz." && echo "snap $n: $size bytes in $parts parts"
  else
    echo "snap $n ($size bytes) left for the next call: $files files, $bytes bytes already"
  fi
  rm -f "$t.gz"
done
tail -n 3 /tmp/res/*.log 2>/dev/null | tail -n 30
for p in $(ls /tmp/work/*/runs/*/seed_*/progress.csv 2>/dev/null | head -n 1); do echo "$p: $(tail -n 1 "$p" | cut -d, -f1-4)"; done
nvidia-smi --query-gpu=name,utilization.gpu,memory.used --format=csv,noheader
left=$(ls /tmp/res/*.tgz 2>/dev/null | xargs -n1 basename 2>/dev/null | grep -vxFf /tmp/res/sent 2>/dev/null | wc -l)
echo "tgz not yet sent: $left"
