#!/usr/bin/env bash
# README command 1: a local multi-process training run on loopback.
#
#   deploy/run-local.sh [--baseline] [--resume|--fresh] [--verbose] [--set KEY=VALUE ...] [PRESET|CONFIG.toml]
#                       [-- extra learner args]
#
# Set-up if needed, release build, then the learner (the embedded zenoh endpoint), one expert server (none under
# expert.placement = "in-actor"), N actors and an eval actor as separate processes. Logs of every process go to
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
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

config=""
baseline=0
verbose=0
learner_args=()
sets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --baseline) baseline=1 ;;
    --resume) learner_args+=(--resume) ;;
    --fresh) learner_args+=(--fresh) ;;
    --verbose) verbose=1 ;;
    --set) [ $# -ge 2 ] || { echo "--set needs KEY=VALUE" >&2; exit 2; }; sets+=(--set "$2"); shift ;;
    -h|--help) sed -n '2,21p' "$0"; exit 0 ;;
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
for b in learner actor expert-server cabc; do
  [ -x "$bin/$b" ] || { echo "[run-local] error: $bin/$b was not built" >&2; exit 1; }
done

extra=()
[ "$baseline" = 1 ] && extra+=(--baseline)
# The learner resolves the configuration (preset or file), writes it into the run folder and prints the folder.
run_dir=$("$bin/learner" prepare ${config:+--config "$config"} "${extra[@]}" "${sets[@]}")
cfg="$run_dir/config.toml"
logs="$run_dir/logs"
mkdir -p "$logs"
actors=$("$bin/cabc" show --config "$cfg" actors.count)
evaluators=$("$bin/cabc" show --config "$cfg" actors.evaluators)
echo "[run-local] run folder $run_dir; $actors actors + $evaluators evaluator(s); logs in $logs" >&2

# The learner hosts the run's bus on its TCP endpoints (bus.listen: tcp/ or tls/ HOST:PORT). One that already
# accepts connections belongs to another run on this machine: this run's learner could not open it, and this run's
# actors would join the other run's bus. Refused here, before any process starts.
listen_ports=()
for endpoint in $(grep -oE '(tcp|tls)/[^",]+' <<<"$("$bin/cabc" show --config "$cfg" bus.listen)"); do
  address=${endpoint#*/}
  address=${address%%[#?]*}
  host=${address%:*}
  host=${host#[}
  host=${host%]}
  case "$host" in 0.0.0.0 | "") host=127.0.0.1 ;; "::") host=::1 ;; esac
  listen_ports+=("$host/${address##*:}")
done
accepting() { (exec 3<>"/dev/tcp/$1") 2>/dev/null; }
for hp in "${listen_ports[@]}"; do
  if accepting "$hp"; then
    echo "[run-local] error: ${hp/\//:} (bus.listen) is in use: another run on this machine? Give this run its own port:" \
      "--set 'bus.listen=[\"tcp/127.0.0.1:PORT\"]' --set 'bus.connect=[\"tcp/127.0.0.1:PORT\"]'" >&2
    exit 1
  fi
done

# This script writes each process's stderr into its log (panics included): the binaries' own log files would be a
# second copy.
export CABC_NO_LOG_FILE=1

pids=()
started=$SECONDS
cleanup() {
  trap - INT TERM EXIT
  echo "[run-local] stopping" >&2
  for p in "${pids[@]}"; do kill -INT "$p" 2>/dev/null || true; done
  sleep 2
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
}
trap cleanup INT TERM EXIT

if [ -t 2 ] && [ "$verbose" = 0 ] && [ -z "${RUST_LOG:-}" ]; then
  # A terminal: the learner writes its own log file and draws its progress bar here, with warnings, errors and a
  # short line per evaluation that completes laps (cabc_proto::telemetry::BRIEF).
  env -u CABC_NO_LOG_FILE CABC_TERMINAL_BRIEF=1 \
    "$bin/learner" run --config "$cfg" --run-dir "$run_dir" "${learner_args[@]}" &
else
  # Not a terminal, or --verbose: the learner's log also goes to stderr, one line per epoch and per evaluation.
  "$bin/learner" run --config "$cfg" --run-dir "$run_dir" "${learner_args[@]}" 2> >(tee -a "$logs/learner.log" >&2) &
fi
learner_pid=$!
pids+=("$learner_pid")
# The others start once the learner's bus accepts connections (up to 60 s; without a TCP endpoint, after 1 s); a
# learner that ends before that (a run folder in use, a bad configuration) ends the run here.
[ ${#listen_ports[@]} -eq 0 ] && sleep 1
for _ in $(seq 1 600); do
  if ! kill -0 "$learner_pid" 2>/dev/null; then
    status=0
    wait "$learner_pid" || status=$?
    echo "[run-local] error: the learner ended (exit $status) before its bus opened; see $logs/learner.log" >&2
    exit $((status == 0 ? 1 : status))
  fi
  ready=1
  for hp in "${listen_ports[@]}"; do accepting "$hp" || ready=0; done
  [ "$ready" = 1 ] && break
  sleep 0.1
done
# Under expert.placement = "in-actor" each actor solves its own relabellings: no server.
# (Binaries older than the key know no placement: a server then.)
placement=$("$bin/cabc" show --config "$cfg" expert.placement 2>/dev/null || echo server)
if [ "$placement" != in-actor ]; then
  "$bin/expert-server" serve --config "$cfg" --id 0 2>> "$logs/expert-server-0.log" &
  pids+=($!)
fi
for i in $(seq 0 $((actors - 1))); do
  "$bin/actor" --config "$cfg" --id "actor-$i" 2>> "$logs/actor-$i.log" &
  pids+=($!)
done
if [ "$evaluators" = 1 ]; then
  "$bin/actor" --config "$cfg" --id eval --eval 2>> "$logs/eval.log" &
  pids+=($!)
else
  # Evaluator i evaluates the versions v with v mod evaluators = i.
  for i in $(seq 0 $((evaluators - 1))); do
    "$bin/actor" --config "$cfg" --id "eval-$i" --eval 2>> "$logs/eval-$i.log" &
    pids+=($!)
  done
fi

status=0
wait "$learner_pid" || status=$?
# The wall clock from the first process started (SECONDS counts from this script's start; the build is before it).
elapsed=$((SECONDS - started))
echo "[run-local] learner finished (exit $status) after $((elapsed / 60)) min $((elapsed % 60)) s; summary: $run_dir/summary.json" >&2
exit "$status"
