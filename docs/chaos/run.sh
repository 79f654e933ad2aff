#!/usr/bin/env bash
# Issue 64's chaos measure: the main job (the default preset) under deploy/chaos.sh, seeds 1-3 (run.seed 42-44),
# one fault every 10-30 s drawn from the chaos seed (a SIGKILL, or since the actors' outbox a SIGKILL or a 5-30 s
# SIGSTOP: `cabc chaos --faults`); each run's report and results copied to docs/chaos/<run>/.
# Beside them, the undisturbed main job on the same seeds: docs/reproduction/v-b-robust-judged-s1..3 (recorded with
# deploy/run-local.sh; early stops at 57, 34, 43), or `--calm` to run them again here as calm-v-b-s<k>.
#
#   docs/chaos/run.sh [--calm] [--router] [--secured] [--prefix P] [SEED ...]      (CABC_BIN=DIR: prebuilt binaries)
#
# --router runs the job with its standalone router under the supervisor (deploy/run-local.sh --router), struck too.
# --secured runs it under mutual TLS (issue 74): deploy/make-certs.sh makes the run's certificates in
# runs/<run>-certs, the bus is tls/, and the supervised router's configuration carries the access control.
# Each run's audit (`cabc audit`: every published segment's fate, from the actors' journals) is in its chaos.json and
# in docs/chaos/<run>/audit.txt.
# --prefix names the runs P-v-b-s<k> (default chaos; the measure of kills alone, before the outbox and the pauses,
# is chaos-v-b-s1..3; the one of kills and pauses with the outbox, chaos-pause-v-b-s<k>).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$root"
calm=0
router=()
secured=0
prefix=chaos
seeds=()
while [ $# -gt 0 ]; do
  case "$1" in
    --calm) calm=1 ;; --router) router=(--router) ;; --secured) secured=1 ;; --prefix) prefix=$2; shift ;;
    *) seeds+=("$1") ;;
  esac
  shift
done
[ ${#seeds[@]} -gt 0 ] || seeds=(1 2 3)
for k in "${seeds[@]}"; do
  port=$((7610 + k))
  [ "$calm" = 1 ] && name=calm-v-b-s$k || name=$prefix-v-b-s$k
  proto=tcp
  secure=()
  if [ "$secured" = 1 ]; then
    proto=tls
    certs="$root/runs/$name-certs"
    deploy/make-certs.sh --host 127.0.0.1 --actors 8 --zenohd "$certs" > /dev/null
    secure=(--set bus.security.mode=mtls --set "bus.security.certs=$certs")
  fi
  endpoint="[\"$proto/127.0.0.1:$port\"]"
  common=(--set "run.seed=$((41 + k))" --set "bus.listen=$endpoint" --set "bus.connect=$endpoint" "${secure[@]}")
  if [ "$calm" = 1 ]; then
    deploy/run-local.sh "${router[@]}" --fresh "${common[@]}" --set "run.name=$name" > "runs/$name.out" 2>&1 || true
  else
    deploy/chaos.sh --seed "$k" "${router[@]}" --fresh "${common[@]}" --set "run.name=$name" > "runs/$name.out" 2>&1 || true
  fi
  mkdir -p "docs/chaos/$name"
  for f in chaos.json summary.json supervision.json metrics.csv evals.csv config.toml; do
    [ -f "runs/$name/$f" ] && cp "runs/$name/$f" "docs/chaos/$name/"
  done
  if [ -d "runs/$name/journal" ]; then
    "${CABC_BIN:-$root/target/release}/cabc" audit "runs/$name" > "docs/chaos/$name/audit.txt" || true
  fi
  echo "[chaos] $name done" >&2
done
