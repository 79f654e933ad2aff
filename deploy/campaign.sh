#!/usr/bin/env bash
# Issue 18's campaign: the paper's protocol (the reference's, `v-*-ref`) against ours over seeds, and the ablations
# that move one protocol item at a time from the reference's to ours, as slices of deploy/reproduce.sh in order of
# priority. Resumable: an ended run is skipped, an interrupted one resumed (run it again, in a later session too).
#
#   deploy/campaign.sh [--pin] [--list] [--only N]
#
# --pin copies the current release binaries to .deps/campaign-bin/<commit>/ and uses them for every later call, so
# that the campaign's runs come from one code whatever is built meanwhile (the folder used is printed, and named in
# docs/reproduction/CAMPAIGN.md by the report). --list prints the slices; --only N runs slice N alone.
# Logs: runs/<run>/logs/, and the campaign's own in runs/campaign.log.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

pin=0
list=0
only=""
while [ $# -gt 0 ]; do
  case "$1" in
    --pin) pin=1 ;;
    --list) list=1 ;;
    --only) only=$2; shift ;;
    -h|--help) sed -n '2,11p' "$0"; exit 0 ;;
    *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
  shift
done

# V-B runs are capped at 200 epochs, as the earlier campaign's (docs/REPRODUCTION.md): a run that has not stopped by
# then is reported as such.
E=200
# The ablations: one protocol item (issue 18's numbering) moved from the reference's value to ours.
ABL_SCHEDULE=(--set 'training.schedule="paper"' --set training.aux_max_batches=2000 --set training.critic_min_uncertain=16)
ABL_CLIP=(--set 'training.clip_scope="policy"')
ABL_COLLECTION=(--set 'collection.episodes="carry"' --set actors.count=2 --set actors.envs_per_actor=4)
ABL_UNCERTAIN=(--set 'collection.flush="with-step"' --set 'collection.expert_failure_staged="uncertain"' --set replay.dynamics_only=true)

# Seed-major: every protocol and ablation at seed 1, then at seed 2, ..., so that each slice of a session adds a
# whole row of the ablation table.
slices=()
for k in 1 2 3; do
  slices+=(
    "--seeds $k-$k --epochs $E v-b-ref"
    "--seeds $k-$k --epochs $E --methods proposed --tag abl-clip ${ABL_CLIP[*]} v-b-ref"
    "--seeds $k-$k --epochs $E --methods proposed --tag abl-schedule ${ABL_SCHEDULE[*]} v-b-ref"
    "--seeds $k-$k --epochs $E --methods proposed --tag abl-collection ${ABL_COLLECTION[*]} v-b-ref"
    "--seeds $k-$k --epochs $E --methods proposed --tag abl-uncertain ${ABL_UNCERTAIN[*]} v-b-ref"
    "--seeds $k-$k --epochs $E --tag rerun v-b"
  )
done
slices+=(
  "--seeds 4-5 --epochs $E v-b-ref"
  "--seeds 4-5 --epochs $E --tag rerun v-b"
  "--seeds 3 v-a-ref"
  "--seeds 3 v-c-ref"
  "--seeds 3 --methods baseline --tag bc --set algorithm.baseline_lambda=0 v-c-ref"
)

if [ "$list" = 1 ]; then
  for i in "${!slices[@]}"; do echo "$i: deploy/reproduce.sh ${slices[$i]}"; done
  exit 0
fi

pinned="$root/.deps/campaign-bin/current"
if [ "$pin" = 1 ]; then
  commit=$(git rev-parse --short HEAD)
  [ -z "$(git status --porcelain -- ':!docs' ':!runs')" ] || echo "[campaign] warning: the work tree differs from $commit" >&2
  "$root/deploy/setup.sh"
  cargo build --release --quiet --bins
  dest="$root/.deps/campaign-bin/$commit"
  mkdir -p "$dest"
  cp target/release/learner target/release/actor target/release/expert-server "$dest/"
  ln -sfn "$dest" "$pinned"
  echo "[campaign] pinned the binaries of $commit in $dest" >&2
fi
[ -x "$pinned/learner" ] || { echo "[campaign] no pinned binaries: run with --pin first" >&2; exit 1; }
export CABC_BIN="$pinned"
mkdir -p runs
echo "[campaign] $(date -u +%FT%TZ) binaries $(readlink -f "$pinned")" >> runs/campaign.log
for i in "${!slices[@]}"; do
  [ -z "$only" ] || [ "$only" = "$i" ] || continue
  echo "[campaign] $(date -u +%FT%TZ) slice $i: ${slices[$i]}" | tee -a runs/campaign.log >&2
  # shellcheck disable=SC2086 # the slice is a word list by design
  eval "\"$root/deploy/reproduce.sh\" ${slices[$i]}" >> runs/campaign.log 2>&1 \
    || echo "[campaign] slice $i failed (see runs/campaign.log)" | tee -a runs/campaign.log >&2
done
echo "[campaign] $(date -u +%FT%TZ) done" | tee -a runs/campaign.log >&2
