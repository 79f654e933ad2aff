#!/usr/bin/env bash
# Packs what a session with the lent GPU machine carries there (issue 22): the learner, cabc (its bench-vision) and
# cabc-sim (its camera bench), stripped, and the C
# libraries of its plots that the machine may lack, and the CUDA test, into .gpu/ (git-ignored), with .gpu/run.sh,
# which runs them
# against the machine's own libtorch 2.11.0 (the version this source builds against).
#
#   deploy/gpu-pack.sh            # here; then, with the device tool: carry [".gpu"], command ".gpu/run.sh learner ..."
#   deploy/gpu-pack.sh --scaling  # the learner, the actor and cabc (its supervisor) alone: gpu-session.sh's
#                                 # --part scaling runs actor processes (the full pack and the actor are over 64 MiB)
#
# On that machine PyTorch 2.11.0 lives in /opt/torch/.venv/lib/python3.12/site-packages/torch (its lib/ is
# libtorch); TORCH_LIB overrides that. The binary's runpath names this machine's .deps/, which is not there, so
# LD_LIBRARY_PATH decides. Fails if the pack is over the device tool's 64 MiB.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
scaling=0
case "${1:-}" in --scaling) scaling=1 ;; "") ;; *) echo "[gpu-pack] unknown option $1" >&2; exit 2 ;; esac
"$root/deploy/setup.sh"
cargo build --release --quiet --bin learner --bin cabc --bin cabc-sim --bin actor
# The CUDA test (learning/tests/cuda.rs), which runs there as `.gpu/run.sh cuda-test`.
test_bin=$(cargo test --release --workspace --test cuda --no-run 2>&1 | grep -o 'target/release/deps/cuda-[0-9a-f]*' | head -1)
[ -x "$test_bin" ] || { echo "[gpu-pack] error: the CUDA test was not built" >&2; exit 1; }
rm -rf .gpu && mkdir -p .gpu/lib
strip -o .gpu/learner target/release/learner
strip -o .gpu/cabc target/release/cabc
if [ "$scaling" = 1 ]; then
  strip -o .gpu/actor target/release/actor
else
  strip -o .gpu/cabc-sim target/release/cabc-sim
  strip -o .gpu/cuda-test "$test_bin"
fi
# Everything the binary needs besides glibc, the C++ runtime and libtorch: the plots' fontconfig and freetype and
# what they pull in.
{ ldd target/release/learner; ldd target/release/cabc; } | awk '$3 ~ /^\// {print $1, $3}' | sort -u | while read -r name path; do
  case "$name" in
    libc.so*|libm.so*|libdl.so*|librt.so*|libpthread.so*|libutil.so*|libstdc++.so*|libgcc_s.so*|ld-linux*) ;;
    *) case "$path" in "$root"/.deps/*) ;; *) cp -L "$path" ".gpu/lib/$name" ;; esac ;;
  esac
done
# A font and a fontconfig file that names it alone: that machine has no fonts, and the plots need one (the first
# CUDA run's log: "No such font: sans-serif").
font=$(fc-match -f '%{file}' sans-serif 2>/dev/null || true)
[ -f "$font" ] || { echo "[gpu-pack] error: no sans-serif font here (fc-match)" >&2; exit 1; }
mkdir -p .gpu/fonts
cp -L "$font" .gpu/fonts/
cat > .gpu/fonts/fonts.conf <<'CONF'
<?xml version="1.0"?>
<!DOCTYPE fontconfig SYSTEM "fonts.dtd">
<fontconfig>
  <dir prefix="relative">.</dir>
  <cachedir>/tmp/cabc-fontconfig</cachedir>
  <alias><family>sans-serif</family><prefer><family>DejaVu Sans</family></prefer></alias>
</fontconfig>
CONF
cat > .gpu/run.sh <<'RUN'
#!/usr/bin/env bash
# Runs a packed binary (deploy/gpu-pack.sh) against the machine's libtorch: .gpu/run.sh learner|cabc ARGS...
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
torch_lib=${TORCH_LIB:-/opt/torch/.venv/lib/python3.12/site-packages/torch/lib}
[ -f "$torch_lib/libtorch_cuda.so" ] || { echo "no libtorch_cuda.so in $torch_lib (set TORCH_LIB)" >&2; exit 1; }
export LD_LIBRARY_PATH="$torch_lib:$here/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export FONTCONFIG_FILE="$here/fonts/fonts.conf"
bin=$1; shift
exec "$here/$bin" "$@"
RUN
chmod +x .gpu/run.sh
size=$(du -sm .gpu | cut -f1)
echo "[gpu-pack] .gpu/: $size MB ($(ls .gpu/lib | tr '\n' ' '))" >&2
[ "$size" -le 60 ] || { echo "[gpu-pack] error: $size MB is over what the device tool carries (64 MiB)" >&2; exit 1; }
