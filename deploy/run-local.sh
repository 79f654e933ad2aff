#!/usr/bin/env bash
# README command 1: a local multi-process training run on loopback.
#
#   deploy/run-local.sh [--baseline] [--resume|--fresh] [--verbose] [--set KEY=VALUE ...] [PRESET|CONFIG.toml]
#                       [--router] [--chaos SEED [--chaos-every MIN-MAX]] [-- extra learner args]
#
# Set-up if needed, release build, then the learner (the embedded zenoh endpoint), one expert server (none under
# expert.placement = "in-actor"), N actors and an eval actor as separate processes, under the run's supervisor
# (`cabc supervise`): a process that dies is restarted, a crash loop stops the run. Logs of every process go to
# runs/<run>/logs/. One Ctrl-C stops them all.
# With CABC_BIN=DIR the binaries in DIR are used and nothing is built.
# Default preset: the binaries' (cabc_proto::config::DEFAULT_PRESET: v-b, experiment V-B: the recipe `v-b-recipe`,
# the reference implementation's protocol with DAgger's aggregate, lambda's warm-up and D- as the critic's negatives,
# with the safety term as the paper writes it: frozen f_hat and p_hat, eq. (14)'s rows, the hinged term; it reached
# the early stop on every seed of its campaign; docs/REPRODUCTION.md). --baseline runs the same with lambda = 0;
# v-b-ref is the reference's protocol alone.
# On a terminal the learner draws a progress bar (epoch of the budget, elapsed, time per epoch, beta, D+/D?/D-, the
# last evaluation) and one short line per evaluation that completes laps, with warnings and errors; its whole log
# goes to runs/<run>/logs/learner.log as always. --verbose (or RUST_LOG) brings the full lines to the terminal. Not
# on a terminal (a pipe, CI): the full lines, as the log.
# A run folder that holds a checkpoint is continued with --resume or started over with --fresh.
# --set changes one configuration value (e.g. --set run.seed=3 --set run.name=v-b-s3); repeatable.
# --router puts a standalone router (zenohd, deploy/SCALE-OUT.md §2) under the supervisor too, on bus.connect: every
# process dials it, the learner too (bus.listen = []), and it is restarted when it dies like the others.
# --chaos SEED runs it under `cabc chaos`: a process killed or paused every 10-30 s (--chaos-every), drawn from SEED,
# and the report in runs/<run>/chaos.json (deploy/chaos.sh); with --router the router is struck too.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

config=""
chaos=()
chaos_every=()
baseline=0
router=0
verbose=0
learner_args=()
sets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --baseline) baseline=1 ;;
    --resume) learner_args+=(--resume) ;;
    --fresh) learner_args+=(--fresh) ;;
    --verbose) verbose=1 ;;
    --chaos) [ $# -ge 2 ] || { echo "--chaos needs a seed" >&2; exit 2; }; chaos=(--seed "$2"); shift ;;
    --chaos-every) [ $# -ge 2 ] || { echo "--chaos-every needs MIN-MAX" >&2; exit 2; }; chaos_every=(--every "$2"); shift ;;
    --set) [ $# -ge 2 ] || { echo "--set needs KEY=VALUE" >&2; exit 2; }; sets+=(--set "$2"); shift ;;
    --router) router=1 ;;
    -h|--help) sed -n '2,27p' "$0"; exit 0 ;;
    --) shift; learner_args+=("$@"); break ;;
    -*) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    *) config=$1 ;;
  esac
  shift
done

if [ -n "${CABC_BIN:-}" ]; then
  # Prebuilt binaries (deploy/reproduce.sh under deploy/campaign.sh): nothing is built.
  bin=$CABC_BIN
else
  "$root/deploy/setup.sh"
  echo "[run-local] building (release)" >&2
  cargo build --release --quiet --bins
  bin="$root/target/release"
fi
programs=(learner actor expert-server cabc)
[ "$router" = 1 ] && programs+=(zenohd)
for b in "${programs[@]}"; do
  [ -x "$bin/$b" ] || { echo "[run-local] error: $bin/$b was not built" >&2; exit 1; }
done

extra=()
[ "$baseline" = 1 ] && extra+=(--baseline)
# Under a supervised router the learner dials it as the others do.
[ "$router" = 1 ] && sets+=(--set 'bus.listen=[]')
# The learner resolves the configuration (preset or file), writes it into the run folder and prints the folder.
run_dir=$("$bin/learner" prepare ${config:+--config "$config"} "${extra[@]}" "${sets[@]}")
cfg="$run_dir/config.toml"
logs="$run_dir/logs"
mkdir -p "$logs"
actors=$("$bin/cabc" show --config "$cfg" actors.count)
evaluators=$("$bin/cabc" show --config "$cfg" actors.evaluators)
echo "[run-local] run folder $run_dir; $actors actors + $evaluators evaluator(s); logs in $logs" >&2

# The processes run under the run's supervisor (`cabc supervise`, crate supervise/): the learner first, the others
# once its bus accepts connections (a bus endpoint another run on this machine holds is refused before anything
# starts); an expert server unless the actors solve their own relabellings (expert.placement = "in-actor"). A
# process that dies is started again after a backoff (the learner with --resume), with a warning here and in its
# log, and counted in the run folder's supervision.json (metrics.csv's restarts_<role>, summary.json's restarts); one
# that keeps dying (once more after supervision.max_restarts restarts within supervision.window_s) stops the run with an error naming it and
# its log. One Ctrl-C stops them all; the run ends when the learner does, with its exit status.
supervise=()
[ "$verbose" = 1 ] && supervise+=(--verbose)
[ "$router" = 1 ] && supervise+=(--roles router,learner,expert,actor,evaluator)
if [ ${#chaos[@]} -gt 0 ]; then
  # deploy/chaos.sh: the same run under a seeded schedule of faults, reported in $run_dir/chaos.json.
  exec "$bin/cabc" chaos "${chaos[@]}" "${chaos_every[@]}" --config "$cfg" --run-dir "$run_dir" --bin "$bin" \
    "${supervise[@]}" -- "${learner_args[@]}"
fi
exec "$bin/cabc" supervise --config "$cfg" --run-dir "$run_dir" --bin "$bin" "${supervise[@]}" -- "${learner_args[@]}"
