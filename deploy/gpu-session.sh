#!/usr/bin/env bash
# The GPU issue's device checks as prepared calls, sized to the device tool's budget (15 minutes of device time a
# session, 10 minutes a call): run on the lent GPU machine from the repository root, after `deploy/gpu-pack.sh` here,
# with the device tool's `carry: [".gpu"]`:
#
#   bash deploy/gpu-session.sh --part checks --seconds 240    # first call: what can fail, quickly
#   bash deploy/gpu-session.sh --part vc --seconds 500        # then at once, on the warm machine: V-C
#   bash deploy/gpu-session.sh --part quick --seconds 575     # or in one call: the CUDA test, then V-C
#   bash deploy/gpu-session.sh --part scaling --seconds 570   # after deploy/gpu-pack.sh --scaling: collection over
#                                                             # 1, 2, 4, 8, 14 actor processes (issue 66 item 2)
#
# In order, each step bounded so that the next always runs and the results always come back:
#   1. (checks) nvidia-smi, the camera's frames/s on one core and on all, the CUDA test (learning/tests/cuda.rs)
#                                                                                -> $OUT/gpu.log
#   2. (checks) `cabc bench-vision` fp32 and bf16 with the run's Adam and with tch's, each beside PyTorch's own
#      figure for the same network and step, measured in the same call (bench/anchor/vision.py), and against issue
#      31's anchor
#                                                       -> $OUT/bench.jsonl (ours, PyTorch's; fp32, bf16), gpu.log
#   3. (vc) V-C at 224x224 with ResNet-18 (the preset `v-c-224`: `v-c-ref` at the paper's size, bf16, eight
#      environments) for the seconds left, ended by
#      SIGINT (the run's summary says "interrupted"; its checkpoint stays on the machine, and a later call on the
#      same warm machine resumes it)    -> $OUT/{metrics.csv,evals.csv,summary.json,config.toml,laps.png,run.log}
#   4. (scaling) the default preset (--preset) with 1, 2, 4, 8 and 14 actor processes (--actors), each a run of
#      --epochs epochs (the epoch's step budget fixed: the learner deals collection.steps_per_epoch over the actors)
#      under `cabc supervise`, its share of the seconds left; the actors solve their own MPCC (expert.placement =
#      "in-actor", one expert server would be the bottleneck). Per count: collection steps/s (steps taken / collect_s,
#      the median over epochs >= 1), the epoch's, collection's and training's medians, the first 50-lap and early-stop
#      versions if reached                        -> $OUT/scaling.jsonl, scaling-<preset>-<n>/{metrics,evals}.csv, gpu.log
# --part is checks, vc, quick (the CUDA test of step 1, then step 3), scaling, or all (the default: 1-3); --seconds is the whole script's budget (default 560); --side changes
# the image side of steps 2 and 3 (224; a smaller one checks the script itself on a CPU), --bench-args replaces
# bench-vision's timing arguments (the anchor's too). Anywhere else than the device tool, OUT names the folder for
# the results (TORCH_LIB: see .gpu/run.sh; PYTHON the Python with torch and torchvision, default python3).
set -uo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

seconds=560
part=all
side=224
bench_args=""
preset=v-b
actor_counts="1 2 4 8 14"
epochs=12
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds=$2; shift ;;
    --part) part=$2; shift ;;
    --side) side=$2; shift ;;
    --bench-args) bench_args=$2; shift ;;
    --preset) preset=$2; shift ;;
    --actors) actor_counts=$2; shift ;;
    --epochs) epochs=$2; shift ;;
    -h|--help) sed -n '2,24p' "$0"; exit 0 ;;
    *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
  shift
done
case "$part" in checks|vc|quick|scaling|all) ;; *) echo "--part: checks, vc, quick, scaling or all" >&2; exit 2 ;; esac
[ -n "${OUT:-}" ] || { echo "OUT is unset: name the folder for the results" >&2; exit 2; }
[ -x .gpu/run.sh ] || { echo "no .gpu/run.sh: run deploy/gpu-pack.sh here and carry .gpu" >&2; exit 2; }
mkdir -p "$OUT"
log=$OUT/gpu.log
start=$(date +%s)
left() { echo $(( seconds - ($(date +%s) - start) )); }
step() { echo "== $* (at ${SECONDS}s, $(left)s left)" >> "$log"; }

# The anchor: PyTorch 2.11 on the same kind of machine (issue 31): training images/s at batch 64.
declare -A anchor=([fp32]=4256 [bf16]=5635)

# The CUDA test (learning/tests/cuda.rs), bounded by $1 seconds.
cuda_test() {
  step "the CUDA test"
  timeout "$1" .gpu/run.sh cuda-test --nocapture >> "$log" 2>&1
  echo "cuda-test: rc $?" >> "$log"
}

step "nvidia-smi"
nvidia-smi >> "$log" 2>&1 || echo "nvidia-smi: rc $?" >> "$log"

# Issue 66 item 2: collection over actor processes, the epoch's step budget fixed.
if [ "$part" = scaling ]; then
  [ -x .gpu/actor ] || { echo "no .gpu/actor: run deploy/gpu-pack.sh --scaling here" | tee -a "$log" >&2; exit 2; }
  set -- $actor_counts
  count=$#
  for n in "$@"; do
    share=$(( ($(left) - 15) / count ))
    count=$((count - 1))
    name=scaling-$preset-$n
    port=$((7700 + n))
    step "$preset with $n actor processes, $epochs epochs, ${share}s at most"
    [ "$share" -gt 20 ] || { echo "no time left for $n actors" >> "$log"; continue; }
    endpoint="[\"tcp/127.0.0.1:$port\"]"
    dir=$(.gpu/run.sh learner prepare --config "$preset" --set actors.count="$n" --set run.name="$name" \
      --set run.max_epochs="$epochs" --set 'expert.placement="in-actor"' --set "bus.listen=$endpoint" \
      --set "bus.connect=$endpoint" 2>> "$log")
    timeout -s INT -k 20 "$share" .gpu/run.sh cabc supervise --config "$dir/config.toml" --run-dir "$dir" \
      --bin "$root/.gpu" -- --fresh > "$OUT/$name.log" 2>&1
    echo "supervise $n: rc $?" >> "$log"
    mkdir -p "$OUT/$name"
    for f in metrics.csv evals.csv summary.json config.toml; do cp "$dir/$f" "$OUT/$name/" 2>/dev/null || true; done
    tail -n 60 "$OUT/$name.log" > "$OUT/$name/run.log"
    rm -f "$OUT/$name.log"
    python3 - "$OUT/$name" "$n" >> "$OUT/scaling.jsonl" 2>> "$log" <<'PY'
import csv, json, statistics, sys
folder, n = sys.argv[1], int(sys.argv[2])
rows = list(csv.DictReader(open(f"{folder}/metrics.csv")))
later = [r for r in rows if int(r["epoch"]) >= 1] or rows
def med(key):
    values = [float(r[key]) for r in later if r.get(key)]
    return statistics.median(values) if values else None
rate = [float(r["steps_taken"]) / float(r["collect_s"]) for r in later if float(r.get("collect_s") or 0) > 0]
try:
    summary = json.load(open(f"{folder}/summary.json"))
except OSError:
    summary = {}
print(json.dumps({"actors": n, "epochs": len(rows), "collect_steps_per_s": statistics.median(rate) if rate else None,
                  "epoch_s": med("epoch_s"), "collect_s": med("collect_s"), "train_s": med("train_s"),
                  "first_50_laps": summary.get("first_version_with_eval_laps"),
                  "early_stop": summary.get("early_stop_version")}))
PY
  done
  python3 - "$OUT/scaling.jsonl" >> "$log" 2>&1 <<'PY'
import json, sys
lines = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
base = next((l["collect_steps_per_s"] for l in lines if l["actors"] == 1 and l["collect_steps_per_s"]), None)
print("| actors | epochs | collection steps/s | of linear | epoch s | collect s | train s | first 50 laps | early stop |")
print("|---|---|---|---|---|---|---|---|---|")
for l in lines:
    rate = l["collect_steps_per_s"]
    of_linear = f"{rate / (base * l['actors']):.0%}" if rate and base else "–"
    fmt = lambda x: "–" if x is None else (f"{x:.2f}" if isinstance(x, float) else str(x))
    print(f"| {l['actors']} | {l['epochs']} | {fmt(rate)} | {of_linear} | {fmt(l['epoch_s'])} | {fmt(l['collect_s'])} "
          f"| {fmt(l['train_s'])} | {fmt(l['first_50_laps'])} | {fmt(l['early_stop'])} |")
PY
  step "done"
  cat "$log"
  exit 0
fi
[ "$part" = quick ] && cuda_test 90
[ "$part" = vc ] || [ "$part" = quick ] || {
step "the camera on one core and on all (cabc-sim bench)"
timeout 30 .gpu/run.sh cabc-sim bench --seconds 1 >> "$log" 2>&1
echo "cabc-sim bench: rc $?" >> "$log"
cuda_test 150

for precision in fp32 bf16; do
  for optimiser in run tch; do
    step "bench-vision $precision, optimiser $optimiser"
    # shellcheck disable=SC2086 # bench_args is a list of words
    timeout 90 .gpu/run.sh cabc bench-vision --side "$side" --precision "$precision" --optimiser "$optimiser" \
      $bench_args > "$OUT/ours-$optimiser.json" 2>> "$log"
    echo "bench-vision $precision $optimiser: rc $?" >> "$log"
  done
  step "PyTorch $precision"
  # shellcheck disable=SC2086
  timeout 90 "${PYTHON:-python3}" bench/anchor/vision.py --side "$side" --precision "$precision" $bench_args \
    > "$OUT/theirs.json" 2>> "$log"
  echo "PyTorch $precision: rc $?" >> "$log"
  python3 - "$OUT/theirs.json" "${anchor[$precision]}" "$OUT/bench.jsonl" "$OUT"/ours-*.json >> "$log" 2>&1 <<'PY'
import json, sys
theirs, fixed, out = json.load(open(sys.argv[1])), float(sys.argv[2]), sys.argv[3]
b = theirs["train_images_per_s"]
with open(out, "a") as lines:
    lines.write(json.dumps(theirs) + "\n")
    for f in sys.argv[4:]:
        ours = json.load(open(f))
        lines.write(json.dumps(ours) + "\n")
        a = ours["train_images_per_s"]
        print(f"{ours['precision']} on {ours['device']}, optimiser {ours['optimiser']}: {a:.0f} training images/s "
              f"at batch {ours['batch']}, side {ours['side']}; PyTorch's here {b:.0f}: {a / b:.1%}; issue 31's "
              f"anchor {fixed:.0f}: {a / fixed:.1%}; inference ours {ours['infer_images_per_s']}, PyTorch's "
              f"{theirs['infer_images_per_s']}")
PY
  rm -f "$OUT"/ours-*.json "$OUT/theirs.json"
done
}

[ "$part" = checks ] || {
run=v-c-224
[ "$side" = 224 ] || run=v-c-224-side$side
budget=$(( $(left) - 25 ))
step "V-C at ${side}x${side} (v-c-224) for ${budget}s"
if [ "$budget" -gt 30 ]; then
  resume=()
  [ -d "runs/$run/checkpoint" ] && resume=(--resume)
  timeout -s INT -k 20 "$budget" .gpu/run.sh learner run --local --config v-c-224 \
    --set observation.width="$side" --set observation.height="$side" --set run.name="$run" "${resume[@]}" \
    > "$OUT/run.full.log" 2>&1
  echo "learner: rc $? (124 or 130: ended by the budget)" >> "$log"
  tail -n 400 "$OUT/run.full.log" > "$OUT/run.log"
  rm -f "$OUT/run.full.log"
  for f in metrics.csv evals.csv summary.json config.toml plots/laps.png; do
    cp "runs/$run/$f" "$OUT/" 2>> "$log" || true
  done
else
  echo "no time left for V-C" >> "$log"
fi
}
step "done"
cat "$log"
