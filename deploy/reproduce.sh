#!/usr/bin/env bash
# The reproduction campaign: each experiment, proposed and --baseline, over seeds, one run after the other.
#
#   deploy/reproduce.sh [--seeds N] [--epochs E] [--dry-run] [EXPERIMENT ...]
#
# EXPERIMENT is a preset (default: v-b v-a-cpu v-c-cpu). Seed k (1..N) runs with run.seed = 41 + k, so seed 1 is
# the presets' 42; --epochs E caps run.max_epochs (default: the preset's). Run folders are runs/<exp>-s<k> and
# runs/<exp>-s<k>-baseline. An interrupted campaign resumes where it stopped: a run with summary.json from an
# ended run is skipped, a run with a checkpoint is resumed, any other starts fresh. After each run its results
# (summary.json, metrics.csv, evals.csv, plots) are copied to docs/reproduction/<run>/ and the comparison figures
# of its experiment redrawn with `learner compare` into docs/reproduction/<exp>-*.png, its tables (per run, and per
# method over seeds: median and range) into docs/reproduction/<exp>-table.md.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

seeds=1
epochs=""
dry=0
experiments=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift ;;
    --epochs) epochs=$2; shift ;;
    --dry-run) dry=1 ;;
    -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
    -*) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    *) experiments+=("$1") ;;
  esac
  shift
done
[ ${#experiments[@]} -gt 0 ] || experiments=(v-b v-a-cpu v-c-cpu)
[[ "$seeds" =~ ^[1-9][0-9]*$ ]] || { echo "--seeds needs a positive number" >&2; exit 2; }
[ -z "$epochs" ] || [[ "$epochs" =~ ^[1-9][0-9]*$ ]] || { echo "--epochs needs a positive number" >&2; exit 2; }

"$root/deploy/setup.sh"
cargo build --release --quiet --bins
learner="$root/target/release/learner"
runs_dir=runs
out=docs/reproduction
mkdir -p "$out"

# ended: a summary.json whose run was not interrupted.
ended() {
  [ -f "$1/summary.json" ] && ! grep -q '"ended": *"interrupted"' "$1/summary.json"
}

for exp in "${experiments[@]}"; do
  for k in $(seq 1 "$seeds"); do
    for variant in proposed baseline; do
      name="$exp-s$k"
      args=()
      if [ "$variant" = baseline ]; then name="$name-baseline"; args+=(--baseline); fi
      args+=(--set "run.seed=$((41 + k))" --set "run.name=$name")
      [ -z "$epochs" ] || args+=(--set "run.max_epochs=$epochs")
      dir="$runs_dir/$name"
      if ended "$dir"; then
        echo "[reproduce] $name: done ($(grep -o '"ended": *"[^"]*"' "$dir/summary.json"))" >&2
      else
        if [ -d "$dir/checkpoint" ] || [ -d "$dir/checkpoint.old" ]; then mode=--resume; else mode=--fresh; fi
        echo "[reproduce] $name: run-local.sh $mode ${args[*]} $exp" >&2
        if [ "$dry" = 0 ]; then
          "$root/deploy/run-local.sh" "$mode" "${args[@]}" "$exp"
        fi
      fi
      if [ "$dry" = 0 ] && [ -d "$dir" ]; then
        mkdir -p "$out/$name"
        for f in summary.json metrics.csv evals.csv config.toml; do
          [ -f "$dir/$f" ] && cp "$dir/$f" "$out/$name/"
        done
        [ -d "$dir/plots" ] && cp -r "$dir/plots" "$out/$name/"
      fi
    done
  done
  if [ "$dry" = 0 ]; then
    folders=()
    for d in "$out/$exp"-s*; do [ -f "$d/metrics.csv" ] && folders+=("$d"); done
    if [ ${#folders[@]} -gt 0 ]; then
      if "$learner" compare --out "$out/$exp" "${folders[@]}" > "$out/$exp-table.md"; then
        cat "$out/$exp-table.md"
      else
        echo "[reproduce] compare $exp failed" >&2
      fi
    fi
  fi
done
echo "[reproduce] done; results in $out/" >&2
