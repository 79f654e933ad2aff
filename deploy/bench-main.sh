#!/usr/bin/env bash
# The main job against its floor (issue 75): `deploy/run-local.sh` to its end on each seed, one after the other, then
# per run its wall clock, collection, training and the rest (checkpoints, auto-labelling, evaluations' waits,
# start-up), and the floor
#
#   floor = steps collected x MPCC step / cores + training
#
# with the MPCC step the p50 of `expert-server bench --steps 1000 --repeat 3` on one core, measured first. Prints a
# table and the medians; writes everything to runs/bench-main-<tag>.json. A benchmark, not a test: run it alone on
# the machine (another job on the same cores shows up in every figure).
#
#   deploy/bench-main.sh [--seeds 2004,2005,2006,2007,2008] [--tag T] [--set KEY=VALUE ...] [PRESET|CONFIG.toml]
#
# With CABC_BIN=DIR the binaries in DIR are used (an older build, side by side) and nothing is built.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

seeds=2004,2005,2006,2007,2008
tag=now
sets=()
preset=""
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift ;;
    --tag) tag=$2; shift ;;
    --set) sets+=(--set "$2"); shift ;;
    -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
    -*) echo "[bench-main] unknown option $1 (see --help)" >&2; exit 2 ;;
    *) preset=$1 ;;
  esac
  shift
done
[[ "$seeds" =~ ^[0-9]+(,[0-9]+)*$ ]] || { echo "[bench-main] --seeds needs numbers separated by commas" >&2; exit 2; }
[[ "$tag" =~ ^[A-Za-z0-9_.-]+$ ]] || { echo "[bench-main] --tag: letters, digits, '.', '_', '-'" >&2; exit 2; }

if [ -z "${CABC_BIN:-}" ]; then
  "$root/deploy/setup.sh"
  echo "[bench-main] building (release)" >&2
  cargo build --release --quiet --bins
  export CABC_BIN="$root/target/release"
fi
cores=$(nproc)
# The MPCC's own step: the run's expert.* settings apply to it (older binaries take no --set, and need none).
expert_sets=()
for s in ${sets[@]+"${sets[@]}"}; do
  [[ "$s" == expert.* ]] && expert_sets+=(--set "$s")
done
echo "[bench-main] MPCC step on one core: $CABC_BIN/expert-server bench --steps 1000 --repeat 3 ${expert_sets[*]} $preset" >&2
mpcc_json=$(taskset -c 0 "$CABC_BIN/expert-server" bench --steps 1000 --repeat 3 ${expert_sets[@]+"${expert_sets[@]}"} \
  ${preset:+--config "$preset"})

runs=()
walls=()
for seed in ${seeds//,/ }; do
  name="bench-main-$tag-$seed"
  echo "[bench-main] seed $seed: deploy/run-local.sh --fresh --set run.seed=$seed --set run.name=$name ${sets[*]} $preset" >&2
  began=$(date +%s%N)
  "$root/deploy/run-local.sh" --fresh --set "run.seed=$seed" --set "run.name=$name" ${sets[@]+"${sets[@]}"} \
    ${preset:+"$preset"} > "/tmp/$name.log" 2>&1 \
    || { echo "[bench-main] $name failed: see /tmp/$name.log" >&2; exit 1; }
  ended=$(date +%s%N)
  runs+=("runs/$name")
  walls+=("$(( (ended - began) / 1000000 ))")
done

python3 - "$tag" "$cores" "$mpcc_json" "${runs[*]}" "${walls[*]}" <<'EOF'
import csv, json, statistics, sys
tag, cores, mpcc, runs, walls = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3]), sys.argv[4].split(), sys.argv[5].split()
step_ms = mpcc["single_stream"]["step_ms_p50"]
rows = []
for run, wall in zip(runs, (int(w) / 1e3 for w in walls)):
    metrics = list(csv.DictReader(open(f"{run}/metrics.csv")))
    summary = json.load(open(f"{run}/summary.json"))
    actors = next(l.split("=")[1].strip() for l in open(f"{run}/config.toml") if l.startswith("count ="))
    steps = sum(int(r["steps_taken"]) for r in metrics)
    collect = sum(float(r["collect_s"]) for r in metrics)
    train = sum(float(r["train_s"]) for r in metrics)
    mpcc_floor = steps * step_ms / 1e3 / cores
    floor = mpcc_floor + train
    rows.append({"run": run, "actors": int(actors), "epochs": len(metrics), "ended": summary.get("ended"),
                 "early_stop_version": summary.get("early_stop_version"), "wall_s": wall, "collect_s": collect,
                 "train_s": train, "rest_s": wall - collect - train, "steps": steps,
                 "collect_ms_per_step": 1e3 * collect / max(steps, 1), "collect_over_mpcc_floor": collect / mpcc_floor,
                 "floor_s": floor, "wall_over_floor": wall / floor})
print(f"MPCC step p50 on one core: {step_ms:.3f} ms; {cores} cores")
print("| run | actors | epochs | wall | collection | training | rest | collection / step | collection / its floor | floor | wall / floor |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['run']} | {r['actors']} | {r['epochs']} | {r['wall_s']:.1f} s | {r['collect_s']:.1f} s | {r['train_s']:.1f} s "
          f"| {r['rest_s']:.1f} s | {r['collect_ms_per_step']:.2f} ms | {r['collect_over_mpcc_floor']:.2f} | {r['floor_s']:.1f} s "
          f"| {r['wall_over_floor']:.2f} |")
median = lambda k: statistics.median(r[k] for r in rows)
print(f"medians: wall {median('wall_s'):.1f} s, collection {median('collect_s'):.1f} s, training {median('train_s'):.1f} s, "
      f"floor {median('floor_s'):.1f} s, wall / floor {median('wall_over_floor'):.2f}")
out = f"runs/bench-main-{tag}.json"
json.dump({"mpcc_step_ms_p50": step_ms, "mpcc": mpcc, "cores": cores, "runs": rows}, open(out, "w"), indent=1)
print(f"written to {out}")
EOF
