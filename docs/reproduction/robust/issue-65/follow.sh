#!/usr/bin/env bash
# Issue 65 item 3 beside a running campaign: every few minutes, unseen.sh on each V-C run of plan issue-65 (the
# ten-seed groups and the judged block) that has ended here (its summary.json written) and has no study yet, for
# HOURS hours (default 3). Run folders and their policies do not outlive a machine.
#
#   nice -n 10 docs/reproduction/robust/issue-65/follow.sh > runs/issue65-follow.out 2>&1 &
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../../.." && pwd)
cd "$root"
here=docs/reproduction/robust/issue-65
end=$(( $(date +%s) + ${HOURS:-3} * 3600 ))
while [ "$(date +%s)" -lt "$end" ]; do
  for dir in runs/v-c-ref-*ten-s* runs/v-c-ref-variant-judged-s*; do
    name=$(basename "$dir")
    if [ -f "$dir/summary.json" ] && [ -f "$dir/best-policy.safetensors" ] && [ ! -f "$here/$name/unseen.json" ]; then
      "$here/unseen.sh" "$name" || echo "[follow] $name: the study failed" >&2
    fi
  done
  sleep 300
done
