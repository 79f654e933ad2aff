#!/usr/bin/env bash
# README command 2: set-up, release build, then every test of the workspace.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
"$root/deploy/setup.sh"
export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}
start=$(date +%s)
# The end-to-end tests start the release binaries (zenohd among them, third_party/zenohd), so build them first.
cargo build --release --workspace --bins
echo "[test] release build took $(( $(date +%s) - start )) s" >&2
cargo test --release --workspace "$@"

# The Python package (python/, a member of the workspace whose lib has no Rust tests; issue 20): the wheel (maturin,
# abi3) and its tests (python/tests) against the binaries built above. Its format and lints are the workspace's
# (`cargo fmt`, `cargo clippy --workspace --all-targets`).
venv="$root/.deps/venv"
[ -x "$venv/bin/maturin" ] || { echo "[test] error: $venv has no maturin: deploy/setup.sh installs it" >&2; exit 1; }
export PYO3_PYTHON="$venv/bin/python"
rm -rf target/python/wheels
(cd python && "$venv/bin/maturin" build --release --out ../target/python/wheels)
"$venv/bin/pip" install --quiet --disable-pip-version-check --force-reinstall --no-deps target/python/wheels/cabc-*.whl
CABC_BIN_DIR="$root/target/release" "$venv/bin/python" -m pytest -q python/tests
