#!/usr/bin/env bash
# Issue 59 item 3: the main job on its default with the robust keys (DART, sensor noise), as a user runs it, idle,
# seeds 42-44, one after another; kept as docs/reproduction/v-b-robust-s<k> (the default before them:
# v-b-main-s<k>, measure.sh).
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)
cd "$root"
mkdir -p /tmp/logs
for k in 1 2 3; do
  seed=$((41 + k))
  echo "[vb-idle] $(date -u +%FT%TZ) seed $seed" >&2
  deploy/run-local.sh --fresh --set run.seed=$seed --set run.name=v-b-robust-s$k > /tmp/logs/v-b-robust-s$k.log 2>&1
  tail -n1 /tmp/logs/v-b-robust-s$k.log >&2
done
echo "[vb-idle] $(date -u +%FT%TZ) done" >&2
