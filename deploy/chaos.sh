#!/usr/bin/env bash
# The main job under a seeded schedule of faults (issue 64): deploy/run-local.sh under `cabc chaos` instead of
# `cabc supervise`. Every MIN-MAX seconds (default 10-30) one of the run's processes (learner, expert server, actor,
# evaluator) is killed with SIGKILL (the supervisor restarts it) or paused for 5-30 s with SIGSTOP (its links go
# silent; past zenoh's 10 s lease its peers drop them, as a cut link looks from their side; a paused learner is the
# run's router, so every link goes), drawn from the seed; when the run ends, runs/<run>/chaos.json says the
# faults, the restarts, the time each fault cost, the stalls, the steps published and stored, the duplicates and the
# early stop (also printed).
#
#   deploy/chaos.sh [--seed N] [--every MIN-MAX] [run-local.sh's arguments: --set KEY=VALUE ..., PRESET ...]
#
# The faults are injected on purpose, so the supervisor's crash-loop stop is off here (supervision.max_restarts =
# 1000) and its window shorter (supervision.window_s = 60: a process killed again a minute later restarts after the
# first backoff, not a doubled one); a --set of either after these wins. A real crash loop is what
# tests/tests/survive.rs's a_process_that_keeps_dying_stops_the_run_and_is_named checks.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
seed=1
every=10-30
args=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seed) seed=$2; shift ;;
    --every) every=$2; shift ;;
    -h|--help) sed -n '2,13p' "$0"; exit 0 ;;
    *) args+=("$1") ;;
  esac
  shift
done
exec "$root/deploy/run-local.sh" --chaos "$seed" --chaos-every "$every" \
  --set supervision.max_restarts=1000 --set supervision.window_s=60 "${args[@]}"
