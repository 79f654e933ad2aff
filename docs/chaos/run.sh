#!/usr/bin/env bash
# Issue 64's chaos measure: the main job (the default preset) under deploy/chaos.sh, seeds 1-3 (run.seed 42-44),
# one SIGKILL every 10-30 s drawn from the chaos seed; each run's report and results copied to docs/chaos/<run>/.
# Beside them, the undisturbed main job on the same seeds: docs/reproduction/v-b-robust-judged-s1..3 (recorded with
# deploy/run-local.sh; early stops at 57, 34, 43), or `--calm` to run them again here as calm-v-b-s<k>.
#
#   docs/chaos/run.sh [--calm] [SEED ...]      (CABC_BIN=DIR: prebuilt binaries)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$root"
calm=0
seeds=()
for a in "$@"; do
  case "$a" in --calm) calm=1 ;; *) seeds+=("$a") ;; esac
done
[ ${#seeds[@]} -gt 0 ] || seeds=(1 2 3)
for k in "${seeds[@]}"; do
  port=$((7610 + k))
  endpoint="[\"tcp/127.0.0.1:$port\"]"
  common=(--set "run.seed=$((41 + k))" --set "bus.listen=$endpoint" --set "bus.connect=$endpoint")
  if [ "$calm" = 1 ]; then
    name=calm-v-b-s$k
    deploy/run-local.sh --fresh "${common[@]}" --set "run.name=$name" > "runs/$name.out" 2>&1 || true
  else
    name=chaos-v-b-s$k
    deploy/chaos.sh --seed "$k" --fresh "${common[@]}" --set "run.name=$name" > "runs/$name.out" 2>&1 || true
  fi
  mkdir -p "docs/chaos/$name"
  for f in chaos.json summary.json supervision.json metrics.csv evals.csv config.toml; do
    [ -f "runs/$name/$f" ] && cp "runs/$name/$f" "docs/chaos/$name/"
  done
  echo "[chaos] $name done" >&2
done
