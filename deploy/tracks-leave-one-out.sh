#!/usr/bin/env bash
# Issue 76: train on all shipped tracks but one, drive the one left out. Two actors, each on its own track
# (sim.actor_tracks, experts in the actors), the evaluation and the early stop on the first; the curvature preview in
# place of s; the default preset otherwise; seeds 42-46 (runs <name>-s1 .. -s5), both methods. Then
# `deploy/tracks-study.sh` drives each run's best policy on every track.
#
#   deploy/tracks-leave-one-out.sh HELD_OUT [SEEDS]     # HELD_OUT: oval, chicane or long; SEEDS: 1,2,3,4,5
#
# Run folders runs/v-b-loo-<held out>-sK[-baseline]; logs beside them in runs/tracks/. With CABC_BIN=DIR the
# binaries in DIR are used; otherwise deploy/run-local.sh builds them.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
held=${1:?name the track left out: oval, chicane or long}
seeds=${2:-1,2,3,4,5}
case "$held" in
  oval) train='["chicane", "long"]' ;;
  chicane) train='["oval", "long"]' ;;
  long) train='["oval", "chicane"]' ;;
  *) echo "[leave-one-out] unknown track $held (oval, chicane or long)" >&2; exit 2 ;;
esac
first=$(echo "$train" | sed 's/^\["\([a-z-]*\)".*/\1/')
mkdir -p runs/tracks
for k in ${seeds//,/ }; do
  for base in "" "--baseline"; do
    name=v-b-loo-$held-s$k
    dir=runs/$name${base:+-baseline}
    [ -f "$dir/summary.json" ] && continue
    deploy/run-local.sh $base --fresh --set run.name=$name --set run.seed=$((41 + k)) --set actors.count=2 \
      --set run.max_epochs=200 --set observation.track_feature=curvature-preview --set expert.placement=in-actor \
      --set sim.track=$first --set "sim.actor_tracks=$train" > "runs/tracks/$name${base:+-baseline}.log" 2>&1
    echo "[leave-one-out] $dir: exit $?" >&2
  done
done
