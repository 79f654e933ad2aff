#!/usr/bin/env bash
# The GPU issue's device checks as prepared calls, sized to the device tool's budget (15 minutes of device time a
# session, 10 minutes a call): run on the lent GPU machine from the repository root, after `deploy/gpu-pack.sh` here,
# with the device tool's `carry: [".gpu"]`:
#
#   bash deploy/gpu-session.sh --part checks --seconds 240    # first call: what can fail, quickly
#   bash deploy/gpu-session.sh --part vc --seconds 500        # then at once, on the warm machine: V-C
#   bash deploy/gpu-session.sh --part quick --seconds 575     # or in one call: the CUDA test, then V-C
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
# --part is checks, vc, quick (the CUDA test of step 1, then step 3) or all (the default); --seconds is the whole script's budget (default 560); --side changes
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
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds=$2; shift ;;
    --part) part=$2; shift ;;
    --side) side=$2; shift ;;
    --bench-args) bench_args=$2; shift ;;
    -h|--help) sed -n '2,24p' "$0"; exit 0 ;;
    *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
  shift
done
case "$part" in checks|vc|quick|all) ;; *) echo "--part: checks, vc, quick or all" >&2; exit 2 ;; esac
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
