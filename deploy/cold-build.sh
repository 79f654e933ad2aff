#!/usr/bin/env bash
# A cold release build of the run's processes (learner, actor, expert-server) at each REV, one after the other, each
# in a git worktree of its own and a fresh target folder (the dependencies compiled from scratch; libtorch is
# .deps/torch's, not compiled): wall clock, CPU seconds (user + sys, what the build costs whatever else shares the
# cores), peak memory and the number of crates compiled.
#
#   deploy/cold-build.sh REV [REV ...]      e.g. deploy/cold-build.sh bec9204 HEAD
#
# One line per REV on stdout: `rev=<commit> wall_s=.. cpu_s=.. max_rss_mb=.. crates=..`; the build's log in
# .deps/cold-build/<commit>.log. The worktrees and target folders are removed after each build (each is ~5 GB).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
[ $# -gt 0 ] || { sed -n '2,10p' "$0"; exit 2; }
"$root/deploy/setup.sh" >&2
out="$root/.deps/cold-build"
mkdir -p "$out"
for rev in "$@"; do
  commit=$(git rev-parse --short "$rev^{commit}")
  src="$out/src-$commit"
  target="$out/target-$commit"
  rm -rf "$target"
  [ -d "$src" ] || git worktree add --detach "$src" "$commit" >&2
  ln -sfn "$root/.deps" "$src/.deps"
  log="$out/$commit.log"
  (cd "$src" && CARGO_TARGET_DIR="$target" /usr/bin/time -f 'wall_s=%e user_s=%U sys_s=%S max_rss_kb=%M' -o "$out/$commit.time" \
     cargo build --release --bin learner --bin actor --bin expert-server) > "$log" 2>&1
  read -r wall user sys rss < <(sed -E 's/[a-z_]+=//g' "$out/$commit.time")
  crates=$(grep -c '^ *Compiling ' "$log" || true)
  printf 'rev=%s wall_s=%s cpu_s=%s max_rss_mb=%s crates=%s\n' "$commit" "$wall" \
    "$(echo "$user + $sys" | bc)" "$((rss / 1024))" "$crates"
  git worktree remove --force "$src"
  rm -rf "$target"
done
