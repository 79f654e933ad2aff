#!/usr/bin/env bash
# The reproduction campaign: a plan's slices of deploy/reproduce.sh, in order of priority, run by `cabc campaign`
# (crate campaign/). The plans are data, deploy/campaign/<plan>.toml, with the commentary on their slices' results.
# Resumable: an ended run is skipped, an interrupted one resumed (run it again, in a later session too).
#
#   deploy/campaign.sh [--plan recipe|cost|issue-18] [--pin [REV]] [--list] [--status] [--only N[,N...]] [--lane I/N]
#                      [--snapshot] [--tables]
#
# --plan picks the plan: `recipe` (the default, issue 30: the V-B recipe over seeds 42-51, its baseline and its keys
# one at a time), `cost` (the recipe's wall clock, run alone on one lane), `issue-18` (the reference's protocol
# against ours; ended), or a TOML file's path.
# --pin builds the release binaries of REV (default: HEAD; another commit is built in a git worktree beside the
# repo, into the worktree's own target/), copies them (learner, actor, expert-server, cabc) to .deps/campaign-bin/<commit>/, and
# exits (it starts no lane); every later run of a lane uses them, so that the campaign's runs come from one code
# whatever is built meanwhile: a later session on a fresh machine re-pins the campaign's commit with --pin f1047ba
# (the folder used is printed, and named in docs/REPRODUCTION.md by the report). The options below map to the typed command, this checkout's
# (target/release/cabc, built when stale):
#   --list        cabc campaign list --plan P      the slices
#   --status      cabc campaign status --plan P    each slice's runs: ended (and how), in progress (at which epoch)
#                                                  or not started
#   (none)        cabc campaign run --plan P --lane I/N [--only N[,N...]] --bin .deps/campaign-bin/current
#                 --lane I/N is one of N lanes that share the machine's cores, on its own loopback port (7447 + I):
#                 each lane takes the next slice no other lane has claimed (runs/campaign-claims/), so that the lanes
#                 stay busy until the last slice (a run's numbers do not depend on its port or its neighbours; only
#                 its wall clock does); --only N runs slice N alone, --only N,M those (plan order)
#   --tables      cabc campaign tables             redraws every group's figures and table in docs/reproduction/
#                 (the groups with a <group>-table.md) with this checkout's learner (target/release, built), where
#                 the pinned binaries' `cabc compare` predates a column or a figure (the runs' numbers are the
#                 pinned binaries'), and the plans' views over groups ([[view]]), also into docs/REPRODUCTION.md
# --snapshot (bash, copies) copies the tables of the runs still in progress to docs/reproduction/in-progress/ (a
# session ending mid-run commits them) and prints their `cabc compare` table.
# Logs: runs/<run>/logs/, and the campaign's own in runs/campaign[-laneI].log.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

pin=0
pin_rev=HEAD
list=0
only=""
lane="0/1"
snapshot=0
tables=0
status=0
plan=recipe
while [ $# -gt 0 ]; do
  case "$1" in
    --pin) pin=1; if [ $# -ge 2 ] && [[ "$2" != --* ]]; then pin_rev=$2; shift; fi ;;
    --list) list=1 ;;
    --status) status=1 ;;
    --only) only=$2; shift ;;
    --lane) lane=$2; shift ;;
    --snapshot) snapshot=1 ;;
    --tables) tables=1 ;;
    --plan) plan=$2; shift ;;
    -h|--help) sed -n '2,32p' "$0"; exit 0 ;;
    *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
  shift
done

if [ "$snapshot" = 1 ]; then
  out=docs/reproduction/in-progress
  rm -rf "$out" && mkdir -p "$out"
  folders=()
  for dir in runs/*/; do
    dir=${dir%/}
    [ -f "$dir/metrics.csv" ] && [ -f "$dir/config.toml" ] || continue
    if [ -f "$dir/summary.json" ] && ! grep -q '"ended": *"interrupted"' "$dir/summary.json"; then continue; fi
    name=$(basename "$dir")
    grep -q "^name = \"$name\"" "$dir/config.toml" || continue
    mkdir -p "$out/$name"
    cp "$dir/metrics.csv" "$dir/config.toml" "$out/$name/"
    [ -f "$dir/evals.csv" ] && cp "$dir/evals.csv" "$out/$name/"
    folders+=("$out/$name")
  done
  [ ${#folders[@]} -gt 0 ] || { echo "[campaign] no run in progress" >&2; exit 0; }
  bin=$(readlink -f "$root/.deps/campaign-bin/current" 2>/dev/null || echo "$root/target/release")
  "$bin/cabc" compare --out "$out/campaign" "${folders[@]}" | tee "$out/campaign-table.md"
  exit 0
fi

# The typed command (cli/src/campaign.rs, campaign/): this checkout's, built when stale (a no-op when current; the
# runs' binaries are the pinned ones whatever builds it).
cabc() {
  cargo build --release --quiet --workspace --bin cabc  # --workspace: -p would rebuild the dependencies
  "$root/target/release/cabc" "$@"
}

pinned="$root/.deps/campaign-bin/current"
if [ "$pin" = 1 ]; then
  commit=$(git rev-parse --short "$pin_rev^{commit}")
  "$root/deploy/setup.sh"
  if [ "$commit" = "$(git rev-parse --short HEAD)" ]; then
    [ -z "$(git status --porcelain -- ':!docs' ':!runs')" ] || echo "[campaign] warning: the work tree differs from $commit" >&2
    src=$root
  else
    src="$root/.deps/campaign-src-$commit"
    [ -d "$src" ] || git worktree add --detach "$src" "$commit" >&2
    ln -sfn "$root/.deps" "$src/.deps"
  fi
  # Another commit builds into its own target/ (inside its worktree): cargo names a workspace crate's artifacts by
  # its path relative to the workspace, so two checkouts sharing one target/ land on the same files, judged fresh by
  # time alone, and one checkout's binaries could be the other's code (issue 67's build hazard).
  target="$src/target"
  [ "$src" = "$root" ] && target="$root/target"
  (cd "$src" && CARGO_TARGET_DIR="$target" cargo build --release --quiet --bins)
  dest="$root/.deps/campaign-bin/$commit"
  mkdir -p "$dest"
  cp "$target/release/learner" "$target/release/actor" "$target/release/expert-server" "$dest/"
  # cabc (the tools on finished runs) where the commit has it.
  if git cat-file -e "$commit:cli/Cargo.toml" 2>/dev/null; then cp "$target/release/cabc" "$dest/"; fi
  echo "$commit" > "$dest/COMMIT"
  ln -sfn "$dest" "$pinned"
  echo "[campaign] pinned the binaries of $commit in $dest" >&2
  exit 0
fi

if [ "$tables" = 1 ]; then
  # Built every time (a no-op when current): a stale learner would draw last version's tables.
  cargo build --release --quiet --workspace --bins
  exec target/release/cabc campaign tables --compare "target/release/cabc compare"
fi
[ "$status" = 0 ] || { cabc campaign status --plan "$plan"; exit 0; }
[ "$list" = 0 ] || { cabc campaign list --plan "$plan"; exit 0; }

cabc campaign list --plan "$plan" > /dev/null  # builds cabc, and checks the plan before the lane starts
# The lane (exec: its pid, which names its claims, is the typed command's).
exec "$root/target/release/cabc" campaign run --plan "$plan" --lane "$lane" ${only:+--only "$only"} --bin "$pinned"
