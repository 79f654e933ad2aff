#!/usr/bin/env bash
# Issue 65 item 3: the default's (V-B) ten seeds, both methods, run here undisturbed, each followed by unseen.sh on
# its best policy (run folders and their policies do not outlive a machine, so the study runs where each run ends).
# For each K (run.seed 41 + K) and each method: deploy/run-local.sh [--baseline] --fresh as runs/calm-v-b-s<K>[-baseline]
# on its own loopback port (7610 + K; the campaign's lanes use 7447 + I), then its results (summary.json, metrics.csv,
# evals.csv, config.toml) and the study's judge.json / unseen.json go to docs/reproduction/robust/issue-65/<run>/.
# A run that already holds a summary.json is not run again (resumable); its study is redone only if missing.
#
#   [CABC_BIN=DIR] docs/reproduction/robust/issue-65/calm.sh K...      (this checkout's binaries, built, without CABC_BIN)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../../.." && pwd)
cd "$root"
here=docs/reproduction/robust/issue-65
export CABC=${CABC:-${CABC_BIN:+$CABC_BIN/cabc}}
for k in "$@"; do
  port=$((7610 + k))
  endpoint="[\"tcp/127.0.0.1:$port\"]"
  for method in proposed baseline; do
    name=calm-v-b-s$k
    flag=()
    if [ "$method" = baseline ]; then name=$name-baseline; flag=(--baseline); fi
    if [ ! -f "runs/$name/summary.json" ]; then
      deploy/run-local.sh "${flag[@]}" --fresh --set "run.seed=$((41 + k))" --set "bus.listen=$endpoint" \
        --set "bus.connect=$endpoint" --set "run.name=$name" > "runs/$name.out" 2>&1 || true
    fi
    mkdir -p "$here/$name"
    for f in summary.json metrics.csv evals.csv config.toml; do
      [ -f "runs/$name/$f" ] && cp "runs/$name/$f" "$here/$name/"
    done
    [ -f "$here/$name/unseen.json" ] || "$here/unseen.sh" "$name"
    echo "[calm] $name done" >&2
  done
done
