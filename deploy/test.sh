#!/usr/bin/env bash
# README command 2: set-up, release build, then every test of the workspace.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
"$root/deploy/setup.sh"
export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}
start=$(date +%s)
# The end-to-end tests start the release binaries, so build them first.
cargo build --release --workspace --bins
echo "[test] release build took $(( $(date +%s) - start )) s" >&2
cargo test --release --workspace "$@"
