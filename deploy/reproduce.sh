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
# plots) are copied to docs/reproduction/<run>/ and the comparison figures of its group redrawn with `cabc
# compare` into docs/reproduction/<exp>[-<tag>]-*.png, its tables (per run, and per method over seeds: median and
# range) into docs/reproduction/<exp>[-<tag>]-table.md. With CABC_BIN=DIR the binaries in DIR are used and nothing
# is built (a campaign that outlives code changes keeps its binaries; deploy/campaign.sh pins them). Its run names are
# proto/src/run_name.rs's (`cabc campaign status` reads the same folders).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

seeds=1
epochs=""
dry=0
tag=""
methods="proposed baseline"
sets=()
experiments=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift ;;
    --epochs) epochs=$2; shift ;;
    --tag) tag=$2; shift ;;
    --methods) methods=$2; shift ;;
    --set) [ $# -ge 2 ] || { echo "--set needs KEY=VALUE" >&2; exit 2; }; sets+=(--set "$2"); shift ;;
    --dry-run) dry=1 ;;
    -h|--help) sed -n '2,17p' "$0"; exit 0 ;;
    -*) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    *) experiments+=("$1") ;;
  esac
  shift
done
[ ${#experiments[@]} -gt 0 ] || experiments=(v-b v-a-cpu v-c-cpu)
if [[ "$seeds" =~ ^[1-9][0-9]*$ ]]; then first=1; last=$seeds
elif [[ "$seeds" =~ ^([1-9][0-9]*)-([1-9][0-9]*)$ ]]; then first=${BASH_REMATCH[1]}; last=${BASH_REMATCH[2]}
else echo "--seeds needs N or A-B" >&2; exit 2; fi
[ -z "$epochs" ] || [[ "$epochs" =~ ^[1-9][0-9]*$ ]] || { echo "--epochs needs a positive number" >&2; exit 2; }
[ -z "$tag" ] || [[ "$tag" =~ ^[A-Za-z0-9_.-]+$ ]] || { echo "--tag: letters, digits, '-', '_' or '.'" >&2; exit 2; }
for m in $methods; do
  [ "$m" = proposed ] || [ "$m" = baseline ] || { echo "--methods: proposed and/or baseline, not $m" >&2; exit 2; }
done

if [ -n "${CABC_BIN:-}" ]; then
  bin=$(cd "$CABC_BIN" && pwd)
else
  "$root/deploy/setup.sh"
  cargo build --release --quiet --bins
  bin="$root/target/release"
fi
export CABC_BIN="$bin"
cabc="$bin/cabc"
runs_dir=runs
out=docs/reproduction
mkdir -p "$out"

# ended: a summary.json whose run was not interrupted.
ended() {
  [ -f "$1/summary.json" ] && ! grep -q '"ended": *"interrupted"' "$1/summary.json"
}
# A run ended in an earlier session on another machine (runs/ is not kept across machines) has its results in
# docs/reproduction/<run>/: it is not run again.
ended_anywhere() {
  ended "$runs_dir/$1" || ended "$out/$1"
}

for exp in "${experiments[@]}"; do
  group="$exp${tag:+-$tag}"
  for k in $(seq "$first" "$last"); do
    for variant in $methods; do
      name="$group-s$k"
      args=(${sets[@]+"${sets[@]}"})
      if [ "$variant" = baseline ]; then name="$name-baseline"; args+=(--baseline); fi
      args+=(--set "run.seed=$((41 + k))" --set "run.name=$name")
      [ -z "$epochs" ] || args+=(--set "run.max_epochs=$epochs")
      dir="$runs_dir/$name"
      if ended_anywhere "$name"; then
        where=$dir
        ended "$where" || where="$out/$name"
        echo "[reproduce] $name: done ($(grep -o '"ended": *"[^"]*"' "$where/summary.json"))" >&2
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
    for d in "$out/$group"-s*; do [ -f "$d/metrics.csv" ] && folders+=("$d"); done
    if [ ${#folders[@]} -gt 0 ]; then
      if "$cabc" compare --out "$out/$group" "${folders[@]}" > "$out/$group-table.md"; then
        cat "$out/$group-table.md"
      else
        echo "[reproduce] compare $group failed" >&2
      fi
    fi
  fi
done
echo "[reproduce] done; results in $out/" >&2
