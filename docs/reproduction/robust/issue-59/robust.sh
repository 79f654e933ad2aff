#!/usr/bin/env bash
# Issue 59 item 3: `cabc robust` on each named run's best (early-stopped) policy, the issue-45 protocol (50 seeded
# random spawns, 50 laps, without noise and with action noise [0.02, 0.005] and state noise 0.002), its report kept
# as docs/reproduction/robust/issue-59/<run>.json. A report already kept is not redone.
#
#   docs/reproduction/robust/issue-59/robust.sh runs/v-b-dart-s{1..10}{,-baseline}
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
root=$(cd "$here/../../../.." && pwd)
for run in "$@"; do
  name=$(basename "$run")
  [ -f "$here/$name.json" ] && continue
  [ -f "$run/summary.json" ] || { echo "$name: not ended, skipped" >&2; continue; }
  "$root/target/release/cabc" robust "$run" --spawns 50 --laps 50 --action-noise 0.02,0.005 --state-noise 0.002 \
    --levels 0,1 --out "/tmp/robust-$name" > /dev/null
  cp "/tmp/robust-$name/robust.json" "$here/$name.json"
  echo "$name: done" >&2
done
