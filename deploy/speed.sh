#!/usr/bin/env bash
# Speed figures of short runs, from the runs' own metrics: per preset, a fresh run of E epochs (default 30) named
# speed-<preset>[-<tag>], then
#   * the actors' time on the wire and time blocked on the expert, as shares of collection (their `final metrics`);
#   * collection and training seconds per epoch (metrics.csv): median and maximum.
#
#   deploy/speed.sh [--epochs E] [--tag T] [--set KEY=VALUE ...] PRESET ...
#
# Run it alone on the machine: other work on the same cores shows up in every figure.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

epochs=30
tag=""
sets=()
presets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --epochs) epochs=$2; shift ;;
    --tag) tag="-$2"; shift ;;
    --set) sets+=(--set "$2"); shift ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    -*) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    *) presets+=("$1") ;;
  esac
  shift
done
[ ${#presets[@]} -gt 0 ] || { echo "name at least one preset (see --help)" >&2; exit 2; }
[[ "$epochs" =~ ^[1-9][0-9]*$ ]] || { echo "--epochs needs a positive number" >&2; exit 2; }

for preset in "${presets[@]}"; do
  name="speed-$preset$tag"
  "$root/deploy/run-local.sh" --fresh --set "run.name=$name" --set "run.max_epochs=$epochs" \
    ${sets[@]+"${sets[@]}"} "$preset" > "/tmp/$name.log" 2>&1 \
    || { echo "[speed] $name failed: see /tmp/$name.log" >&2; exit 1; }
  python3 - "runs/$name" <<'EOF'
import csv, glob, json, re, statistics, sys
run = sys.argv[1]
shares = {"transport_share": [], "expert_wait_share": []}
for log in sorted(glob.glob(f"{run}/logs/actor-*.log")):
    text = re.sub(r"\x1b\[[0-9;]*m", "", open(log).read())
    found = re.findall(r"final metrics: (\{.*\})", text)
    if found:
        metrics = json.loads(found[-1])
        for key in shares:
            shares[key].append(metrics[key])
rows = list(csv.DictReader(open(f"{run}/metrics.csv")))
collect = [float(r["collect_s"]) for r in rows]
train = [float(r["train_s"]) for r in rows]
pct = lambda v: " ".join(f"{100 * x:.1f} %" for x in v) or "-"
print(f"{run}: {len(rows)} epochs; per actor: on the wire {pct(shares['transport_share'])}, "
      f"blocked on the expert {pct(shares['expert_wait_share'])}; collect_s median {statistics.median(collect):.2f} "
      f"max {max(collect):.2f}; train_s median {statistics.median(train):.2f} max {max(train):.2f}")
EOF
done
