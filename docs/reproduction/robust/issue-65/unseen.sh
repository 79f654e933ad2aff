#!/usr/bin/env bash
# Issue 65 item 3: a run's best policy under `cabc robust` at the early stop's own settings and at settings it never
# used, beside each other. For each RUN (a run folder under runs/ that still holds best-policy.safetensors):
#   judge:  the early stop's spawn ranges (cabc robust's defaults: lateral 0.5 of the half width, heading 0.1 rad,
#           speed 0.5-2 m/s) and its noise (the default's collection.early_stop_*: action [0.02, 0.005], state 0.002);
#   unseen: spawns wider in lateral offset (0.8) and heading (0.2 rad), the same speeds;
# each at noise levels 0, 1 and 2 (2: twice the judge's noise), SPAWNS spawns (default 20), 50 laps after the out-lap
# (the run's eval_laps), seed 7 (the judge's episodes draw from the run's seed and the version instead).
# The reports (`cabc robust`'s robust.json, with each episode's outcome) go to
# docs/reproduction/robust/issue-65/<run>/{judge,unseen}.json.
#
#   docs/reproduction/robust/issue-65/unseen.sh RUN...        (CABC=path to cabc; SPAWNS=n)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../../.." && pwd)
cd "$root"
cabc=${CABC:-target/release/cabc}
spawns=${SPAWNS:-20}
here=docs/reproduction/robust/issue-65
noise=(--action-noise 0.02,0.005 --state-noise 0.002 --levels 0,1,2 --spawns "$spawns" --seed 7)
for run in "$@"; do
  name=$(basename "$run")
  [ -f "runs/$name/best-policy.safetensors" ] || { echo "[unseen] $name: no runs/$name/best-policy.safetensors, skipped" >&2; continue; }
  mkdir -p "$here/$name"
  "$cabc" robust "runs/$name" "${noise[@]}" --out "runs/$name/robust-judge" > /dev/null
  "$cabc" robust "runs/$name" "${noise[@]}" --lateral 0.8 --heading 0.2 --out "runs/$name/robust-unseen" > /dev/null
  cp "runs/$name/robust-judge/robust.json" "$here/$name/judge.json"
  cp "runs/$name/robust-unseen/robust.json" "$here/$name/unseen.json"
  echo "[unseen] $name done" >&2
done
