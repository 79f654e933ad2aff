#!/usr/bin/env bash
# Issue 76's generalisation study: each run's best policy driven on circuits it never saw (and on its own, the
# L-track, for reference) by `cabc robust --track`: 20 random spawns, no added noise, an out-lap and 2 laps each.
# Writes RUN/robust-<track>/robust.json; `python3 docs/tracks/generalisation/table.py RUN...` makes the table.
#
#   deploy/tracks-study.sh RUN [RUN ...]
#
# With CABC_BIN=DIR the binaries in DIR are used; otherwise target/release (built by cargo build --release).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bin=${CABC_BIN:-$root/target/release}
[ $# -gt 0 ] || { sed -n '2,9p' "$0"; exit 2; }
for run in "$@"; do
  for track in l-track-barc oval chicane long; do
    out=$run/robust-$track/robust.json
    [ -f "$out" ] && continue
    "$bin/cabc" robust "$run" --track "$track" --spawns 20 --levels 0 --laps 2 >/dev/null 2>"$run/robust-$track.log" \
      || { echo "[tracks-study] $run on $track failed: $run/robust-$track.log" >&2; exit 1; }
    echo "[tracks-study] $run on $track" >&2
  done
done
