#!/usr/bin/env bash
# The reproduction campaign: each experiment, proposed and --baseline, over seeds, one run after the other.
#
#   deploy/reproduce.sh [--seeds N|A-B] [--epochs E] [--tag T] [--methods "proposed baseline"] [--set KEY=VALUE ...]
#                       [--dry-run] [EXPERIMENT ...]
#
# EXPERIMENT is a preset (default: v-b v-a-cpu v-c-cpu). Seed k (1..N, or A..B) runs with run.seed = 41 + k, so seed 1
# is the presets' 42; --epochs E caps run.max_epochs (default: the preset's). --set changes the runs' configuration
# (an ablation), and --tag names it: run folders are runs/<exp>[-<tag>]-s<k> and runs/<exp>[-<tag>]-s<k>-baseline.
# An interrupted campaign resumes where it stopped: a run with summary.json from an ended run is skipped, a run with
# a checkpoint is resumed, any other starts fresh. After each run its results (summary.json, metrics.csv, evals.csv,
# config.toml; no plots: `cabc plots RUN` redraws them) are copied to docs/reproduction/<run>/ and the comparison
# figures of its group redrawn with `cabc compare` into docs/reproduction/<exp>[-<tag>]-*.png, its tables (per run,
# and per method over seeds: median and range) into docs/reproduction/<exp>[-<tag>]-table.md. With CABC_BIN=DIR the
# binaries in DIR are used and nothing is built (a campaign that outlives code changes keeps its binaries, pinned by
# deploy/campaign.sh). This script builds the binaries and hands over to `cabc reproduce` (campaign/src/reproduce.rs),
# which does the above; the run names are proto/src/run_name.rs's.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
case "${1:-}" in -h|--help) sed -n '2,17p' "$0"; exit 0 ;; esac

if [ -n "${CABC_BIN:-}" ]; then
  bin=$(cd "$CABC_BIN" && pwd)
else
  "$root/deploy/setup.sh"
  cargo build --release --quiet --bins
  bin="$root/target/release"
fi
export CABC_BIN="$bin"
exec "$bin/cabc" reproduce "$@"
