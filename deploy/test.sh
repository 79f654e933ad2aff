#!/usr/bin/env bash
# README command 2: set-up, release build, the check for unused dependencies, then every test of the workspace, the
# learning tests again under the oldest CPU kernels, and the Python package's tests.
#
#   deploy/test.sh [ARGS for cargo test ...]
#
# Every step runs whatever failed before it (cargo test --no-fail-fast: one failing test binary does not hide the
# others), and the script ends with a summary of what failed and a non-zero exit when anything did. Each step's
# output is also kept in target/test-logs/<step>.log.
#
# The oldest kernels (issue 29): libtorch picks its CPU kernels by the machine's instruction set
# (ATEN_CPU_CAPABILITY: default, avx2, avx512) and so does MKL, its matrix products (MKL_ENABLE_INSTRUCTIONS: AVX,
# AVX2, AVX512), so the last bits of a training run differ between machines. The tests that train a network assert
# effects with margins that hold on any x86-64 CPU; running them again with ATEN_CPU_CAPABILITY=default and
# MKL_ENABLE_INSTRUCTIONS=AVX makes a margin tuned to one machine's numerics fail here first. CABC_OLDEST_KERNELS=0
# skips that step.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
"$root/deploy/setup.sh"
export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}
logs="$root/target/test-logs"
mkdir -p "$logs"
failed=()

# step NAME COMMAND...: runs it with its output on the terminal and in $logs/NAME.log; a failure is remembered, and
# the step's time goes to $logs/times.txt (issue 46: the suite's steps before and after a change).
step() {
  local name=$1 began
  shift
  began=$(date +%s)
  echo "[test] $name: $*" >&2
  if ! "$@" 2>&1 | tee "$logs/$name.log"; then
    failed+=("$name")
  fi
  echo "$name $(( $(date +%s) - began )) s" | tee -a "$logs/times.txt" >&2
}

start=$(date +%s)
: > "$logs/times.txt"
# The end-to-end tests start the release binaries (zenohd among them, third_party/zenohd), so build them first: the
# one step whose failure stops the rest.
cargo build --release --workspace --bins
echo "build $(( $(date +%s) - start )) s" | tee -a "$logs/times.txt" >&2
# No crate declares a dependency it does not use (issue 67: each one costs a fresh clone's build time): cargo-machete
# (deploy/setup.sh installs it) reads every crate's sources under the root and exits 1 on a finding. A dependency it
# cannot see used (a derive through a re-export, a feature-only crate) goes into that crate's
# `[package.metadata.cargo-machete] ignored`, with a comment why.
step unused-deps "$root/.deps/tools/bin/cargo-machete" "$root"
step workspace cargo test --release --workspace --no-fail-fast "$@"

if [ "${CABC_OLDEST_KERNELS:-1}" != 0 ]; then
  oldest=(env ATEN_CPU_CAPABILITY=default MKL_ENABLE_INSTRUCTIONS=AVX)
  # --workspace, as the step above: `-p` would resolve the dependencies' features anew and rebuild them (minutes).
  step learning-oldest-kernels "${oldest[@]}" cargo test --release --no-fail-fast --workspace \
    --test train --test recipe --test autolabel --test demo --test algorithm --test local --test probe
fi

# The Python package (python/, a member of the workspace whose lib has no Rust tests; issue 20): the wheel (maturin,
# abi3) and its tests (python/tests) against the binaries built above. Its format and lints are the workspace's
# (`cargo fmt`, `cargo clippy --workspace --all-targets`).
python_tests() {
  local venv="$root/.deps/venv"
  [ -x "$venv/bin/maturin" ] || { echo "[test] error: $venv has no maturin: deploy/setup.sh installs it" >&2; return 1; }
  export PYO3_PYTHON="$venv/bin/python"
  rm -rf target/python/wheels
  (cd python && "$venv/bin/maturin" build --release --out ../target/python/wheels) || return 1
  "$venv/bin/pip" install --quiet --disable-pip-version-check --force-reinstall --no-deps target/python/wheels/cabc-*.whl \
    || return 1
  CABC_BIN_DIR="$root/target/release" "$venv/bin/python" -m pytest -q python/tests
}
step python python_tests

echo "all $(( $(date +%s) - start )) s" | tee -a "$logs/times.txt" >&2
if [ ${#failed[@]} -eq 0 ]; then
  echo "[test] every step passed" >&2
  exit 0
fi
echo "[test] FAILED steps: ${failed[*]}" >&2
for name in "${failed[@]}"; do
  echo "[test] $name (target/test-logs/$name.log):" >&2
  grep -E '^test .* FAILED$|^error: test failed|^error: [0-9]+ targets? failed|^FAILED |[0-9]+ failed' \
    "$logs/$name.log" | sed 's/^/[test]   /' >&2 || echo "[test]   (no test named: see the log)" >&2
done
exit 1
