#!/bin/bash
# Idle measurements for issue 46 (run alone: nothing else on the 2 cores), as run on 2026-11-27 from a checkout at
# /work/main with the binaries of d2c3feb pinned (deploy/campaign.sh --pin d2c3feb); its output is measure.txt.
# usage: measure.sh ab | cand SEED... | recipe SEED... | before SEED... | actors2 SEED...
#   recipe: the main job as it is (`deploy/run-local.sh` on the preset v-b, the in-actor expert), per seed, to the
#   early stop, with the binaries of RECIPE_BIN (default: this checkout's target/release, built by run-local.sh's
#   set-up when absent).
#   before: the main job as issue 46 found it: the checkout and binaries of b7b5da9 (the benchmark, before any change
#   of the issue; `deploy/campaign.sh --pin b7b5da9` builds both, in .deps/campaign-src-b7b5da9 and
#   .deps/campaign-bin/b7b5da9), its `deploy/run-local.sh` on its preset v-b (an expert server over the bus), per seed,
#   to the early stop.
#   actors2: as recipe, with two actors (`--set actors.count=2`: each collects half the epoch's 1,024 steps).
set -u
cd /work/main
export CABC_BIN=/work/main/.deps/campaign-bin/d2c3feb
case "${1:-}" in recipe | actors2) export CABC_BIN=${RECIPE_BIN:-/work/main/target/release} ;; esac
out=/work/measure46.txt
what=$1; shift
port=7460
bus=(--set "bus.listen=[\"tcp/127.0.0.1:$port\"]" --set "bus.connect=[\"tcp/127.0.0.1:$port\"]")
if [ "$what" = ab ]; then
  # The expert's placement, alternating, 12 epochs each: collection per step from metrics.csv.
  for rep in 1 2 3; do
    for p in server in-actor; do
      name=m46-ab-$p-$rep
      t0=$(date +%s.%N)
      deploy/run-local.sh --fresh "${bus[@]}" --set run.name=$name --set run.max_epochs=12 --set "expert.placement=\"$p\"" v-b > /dev/null 2>&1
      t1=$(date +%s.%N)
      python3 - "$name" "$p" "$t0" "$t1" >> $out <<'PY'
import csv,sys
name,p,t0,t1=sys.argv[1],sys.argv[2],float(sys.argv[3]),float(sys.argv[4])
rows=list(csv.DictReader(open(f"/work/main/runs/{name}/metrics.csv")))
ms=[1000*float(r['collect_s'])/max(1,int(r['steps_taken'])) for r in rows[1:]]
ms.sort()
print(f"ab {name} placement={p} epochs={len(rows)} collect_ms_per_step_median={ms[len(ms)//2]:.3f} wall_s={t1-t0:.1f}")
PY
    done
  done
elif [ "$what" = recipe ] || [ "$what" = before ] || [ "$what" = actors2 ]; then
  checkout=/work/main
  key=()
  [ "$what" = actors2 ] && key=(--set actors.count=2)
  if [ "$what" = before ]; then
    checkout=/work/main/.deps/campaign-src-b7b5da9
    export CABC_BIN=/work/main/.deps/campaign-bin/b7b5da9
  fi
  for seed in "$@"; do
    name=m46-$what-$seed
    t0=$(date +%s.%N)
    (cd $checkout && deploy/run-local.sh --fresh "${bus[@]}" --set run.name=$name --set run.seed=$seed "${key[@]}" v-b > /dev/null 2>&1)
    t1=$(date +%s.%N)
    python3 - "$checkout/runs/$name" "$t0" "$t1" "$what" >> $out <<'PY'
import csv,sys,json
run,t0,t1,what=sys.argv[1],float(sys.argv[2]),float(sys.argv[3]),sys.argv[4]
name=run.rsplit('/',1)[1]
d=json.load(open(f"{run}/summary.json"))
rows=list(csv.DictReader(open(f"{run}/metrics.csv")))
ms=sorted(1000*float(r['collect_s'])/max(1,int(r['steps_taken'])) for r in rows)
print(f"{what} {name} epochs={d['epochs']} ended={d['ended'][:40]!r} first50={d.get('first_version_with_eval_laps')} wall_min={(t1-t0)/60:.2f} collect_s={sum(float(r['collect_s']) for r in rows):.0f} train_s={sum(float(r['train_s']) for r in rows):.0f} collect_ms_per_step_median={ms[len(ms)//2]:.3f}")
PY
  done
else
  # The candidate: both speed keys and the in-actor expert, per seed, to the early stop.
  for seed in "$@"; do
    name=m46-cand-$seed
    t0=$(date +%s.%N)
    deploy/run-local.sh --fresh "${bus[@]}" --set run.name=$name --set run.seed=$seed --set training.policy_max_batches=512 --set training.aux_max_batches=512 --set collection.overlap=true --set "expert.placement=\"in-actor\"" v-b > /dev/null 2>&1
    t1=$(date +%s.%N)
    python3 - "$name" "$t0" "$t1" >> $out <<'PY'
import csv,sys,json
name,t0,t1=sys.argv[1],float(sys.argv[2]),float(sys.argv[3])
d=json.load(open(f"/work/main/runs/{name}/summary.json"))
rows=list(csv.DictReader(open(f"/work/main/runs/{name}/metrics.csv")))
print(f"cand {name} epochs={d['epochs']} ended={d['ended'][:40]!r} first50={d.get('first_version_with_eval_laps')} wall_min={(t1-t0)/60:.2f} collect_s={sum(float(r['collect_s']) for r in rows):.0f} train_s={sum(float(r['train_s']) for r in rows):.0f}")
PY
  done
fi
