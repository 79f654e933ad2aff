#!/usr/bin/env bash
# Issue 59: the main job, as a user runs it, idle, seeds 42-44, one after another, run as <NAME>-s<k> (NAME: the
# first argument, default v-b). Item 2 ran `measure.sh` (kept as docs/reproduction/v-b-main-s<k>; the first
# reproduction holds docs/reproduction/v-b-s<k>); item 3, once the default took DART and the sensor noise, ran
# `measure.sh v-b-robust` (kept as docs/reproduction/v-b-robust-s<k>).
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)
cd "$root"
name=${1:-v-b}
mkdir -p /tmp/logs
for k in 1 2 3; do
  seed=$((41 + k))
  echo "[vb-idle] $(date -u +%FT%TZ) seed $seed" >&2
  deploy/run-local.sh --fresh --set run.seed=$seed --set run.name=$name-s$k > /tmp/logs/$name-s$k.log 2>&1
  tail -n1 /tmp/logs/$name-s$k.log >&2
done
echo "[vb-idle] $(date -u +%FT%TZ) done" >&2
