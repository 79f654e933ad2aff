#!/usr/bin/env bash
# Installs everything the build needs, idempotently (a second run takes a second):
#   * libtorch 2.11.0 (the version tch 0.24 pins, and the one the lent GPU machine has), from `pip install torch==2.11.0` into .deps/torch (git-ignored): the only way to get
#     libtorch here. tch finds it through LIBTORCH, set in .cargo/config.toml; binaries carry an rpath to it.
#   * the C libraries of the plots (fontconfig, freetype), when missing and apt is usable;
#   * openssl (deploy/make-certs.sh), when missing and apt is usable.
#   * the Python package's tools (maturin, numpy, gymnasium, pyarrow, pytest) in a virtual environment, .deps/venv.
#   * cargo-machete 0.9.2 (deploy/test.sh's check that no crate declares a dependency it does not use), from
#     crates.io with `cargo install --locked` into .deps/tools (a few minutes the first time).
# (The standalone router of deploy/SCALE-OUT.md §2, zenohd, is a member of the workspace, third_party/zenohd: the
# release build makes it, target/release/zenohd.)
# Prints what it does; fails with a message that names what is missing.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
for arg in "$@"; do
  echo "[setup] unknown option $arg (it takes none; zenohd is built with the workspace now: target/release/zenohd)" >&2
  exit 2
done
TORCH_VERSION=${CABC_TORCH_VERSION:-2.11.0}
deps="$root/.deps"
torch_dir="$deps/torch"
marker="$torch_dir/.cabc-installed-$TORCH_VERSION"

say() { echo "[setup] $*" >&2; }
die() { echo "[setup] error: $*" >&2; exit 1; }

command -v cargo >/dev/null || die "cargo is not on PATH: install Rust (rustup) first"
python=${PYTHON:-python3}
command -v "$python" >/dev/null || die "$python is not on PATH: libtorch is installed with pip, which needs Python 3"

if [ ! -f "$marker" ]; then
  say "installing libtorch $TORCH_VERSION (pip install torch==$TORCH_VERSION, ~4.7 GB with its CUDA libraries) into $torch_dir"
  start=$(date +%s)
  rm -rf "$torch_dir.partial"
  "$python" -m pip install --quiet --disable-pip-version-check --no-cache-dir \
    --target "$torch_dir.partial" "torch==$TORCH_VERSION" \
    || die "pip install torch==$TORCH_VERSION failed (is PyPI reachable?)"
  rm -rf "$torch_dir"
  mv "$torch_dir.partial" "$torch_dir"
  touch "$marker"
  say "libtorch installed in $(( $(date +%s) - start )) s ($(du -sh "$torch_dir" | cut -f1))"
fi
[ -f "$torch_dir/torch/lib/libtorch_cpu.so" ] || die "$torch_dir/torch/lib/libtorch_cpu.so is missing: remove $torch_dir and run again"

if ! pkg-config --exists fontconfig freetype2 2>/dev/null; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    say "installing fontconfig/freetype development files (plots)"
    apt-get update -qq && apt-get install -y -qq pkg-config libfontconfig1-dev libfreetype-dev fonts-dejavu-core >/dev/null
  else
    die "fontconfig and freetype development files are missing: install pkg-config, libfontconfig1-dev and libfreetype-dev"
  fi
fi
if ! command -v openssl >/dev/null; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    say "installing openssl (deploy/make-certs.sh, the secure bus and its tests)"
    apt-get update -qq && apt-get install -y -qq openssl >/dev/null
  else
    die "openssl is missing: install it (deploy/make-certs.sh makes the bus's certificates with it)"
  fi
fi
# The Python package's tools (python/, issue 20): maturin, numpy, gymnasium, pyarrow and pytest at the versions of
# python/requirements-dev.txt, in the virtual environment .deps/venv (deploy/test.sh builds the wheel and runs the Python
# tests with them); installed again when that file changes.
venv="$deps/venv"
requirements="$root/python/requirements-dev.txt"
venv_marker="$venv/.cabc-installed-$(sha256sum "$requirements" | cut -c1-16)"
if [ ! -f "$venv_marker" ]; then
  say "installing the Python package's tools (python/requirements-dev.txt) into $venv"
  rm -rf "$venv"
  "$python" -m venv "$venv" || die "$python -m venv failed (on Debian: apt-get install python3-venv)"
  "$venv/bin/pip" install --quiet --disable-pip-version-check -r "$requirements" \
    || die "pip install -r python/requirements-dev.txt failed (is PyPI reachable? numpy 2.4 needs Python 3.11 or later)"
  touch "$venv_marker"
fi
# cargo-machete (issue 67): deploy/test.sh's unused-deps step; installed again when the pinned version changes.
MACHETE_VERSION=0.9.2
machete="$deps/tools/bin/cargo-machete"
if [ "$("$machete" --version 2>/dev/null)" != "$MACHETE_VERSION" ]; then
  say "installing cargo-machete $MACHETE_VERSION (cargo install --locked) into $deps/tools"
  cargo install --quiet --locked --root "$deps/tools" "cargo-machete@$MACHETE_VERSION" \
    || die "cargo install cargo-machete@$MACHETE_VERSION failed (is crates.io reachable?)"
fi
say "ready (LIBTORCH=$torch_dir/torch, set for cargo in .cargo/config.toml)"
