#!/usr/bin/env bash
# README command 2: set-up, release build, then every test of the workspace.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
# --zenohd: the standalone router of deploy/SCALE-OUT.md §2, for its test in tests/tests/security.rs.
"$root/deploy/setup.sh" --zenohd
export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}
start=$(date +%s)
# The end-to-end tests start the release binaries, so build them first.
cargo build --release --workspace --bins
echo "[test] release build took $(( $(date +%s) - start )) s" >&2
cargo test --release --workspace "$@"

# The Python package (python/, a workspace of its own so that the above needs no Python; issue 20): its format and
# lints, the wheel (maturin, abi3), and its tests (python/tests) against the binaries built above.
venv="$root/.deps/venv"
[ -x "$venv/bin/maturin" ] || { echo "[test] error: $venv has no maturin: deploy/setup.sh installs it" >&2; exit 1; }
export PYO3_PYTHON="$venv/bin/python"
rm -rf target/python/wheels
# From python/, so that cargo reads python/.cargo/config.toml (the build output in target/python).
(cd python && cargo fmt --check && cargo clippy --release --all-targets -- -D warnings \
  && "$venv/bin/maturin" build --release --out ../target/python/wheels)
"$venv/bin/pip" install --quiet --disable-pip-version-check --force-reinstall --no-deps target/python/wheels/cabc-*.whl
CABC_BIN_DIR="$root/target/release" "$venv/bin/python" -m pytest -q python/tests
