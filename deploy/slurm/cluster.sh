#!/usr/bin/env bash
# deploy/slurm/cluster.sh: a real Slurm cluster of NODES nodes on this one machine, for trying cabc's Slurm job and
# for its tests (tests/tests/slurm.rs). Needs root (network namespaces) and Debian's packages, which it installs
# when missing (slurmctld, slurmd, slurm-client, munge).
#
#   deploy/slurm/cluster.sh up DIR [NODES]    make the cluster in DIR (default 2 nodes), start its daemons
#   deploy/slurm/cluster.sh down DIR          stop its daemons by their pids, delete its namespaces and bridge
#   deploy/slurm/cluster.sh env DIR           print the environment that talks to it (SLURM_CONF=...)
#
# Each node runs in its own network namespace with its own address, joined to the others by veth pairs on a
# bridge (10.201.<net>.<k>/24, the controller on .254), so that nothing of a job rides on loopback as it would not
# on a cluster: node n<k> is NodeName=n<k>, NodeAddr=10.201.<net>.<k>, its slurmd started in namespace
# cabc-<tag>-n<k>. The controller (slurmctld) and munged run in this namespace; munged on its own socket in DIR
# (a system munged, if any, is left alone). The filesystem is shared, as a cluster's is: a job's run folder is
# where it was submitted. After `up`, `source <(deploy/slurm/cluster.sh env DIR)` and sbatch/squeue/scontrol talk
# to it. Every daemon's pid is in DIR/*.pid and `down` stops exactly those; nothing else is killed.
set -euo pipefail

usage() { sed -n '2,16p' "$0" >&2; exit 2; }
[ $# -ge 2 ] || usage
cmd=$1
dir=$2
nodes=${3:-2}

say() { echo "[slurm-cluster] $*" >&2; }
die() { echo "[slurm-cluster] error: $*" >&2; exit 1; }

# One tag per cluster (its subnet 10.201.<tag>.0/24, bridge cabcbr<tag>, namespaces cabc-<tag>-n<k>, controller
# port): the first free one from the folder's checksum on, kept in DIR/tag for `down`.
tag_of() {
  local t
  t=$(printf '%s' "$1" | cksum | awk '{print $1 % 200 + 20}')
  for _ in $(seq 200); do
    ip link show "cabcbr$t" >/dev/null 2>&1 || { echo "$t"; return; }
    t=$(( (t - 20 + 1) % 200 + 20 ))
  done
  die "no free tag for a cluster (200 bridges cabcbr* exist)"
}

case "$cmd" in
  env)
    [ -f "$dir/slurm.conf" ] || die "$dir/slurm.conf: no cluster made there (cluster.sh up $dir)"
    echo "export SLURM_CONF=$(cd "$dir" && pwd)/slurm.conf"
    exit 0 ;;
  up|down) ;;
  *) usage ;;
esac

[ "$(id -u)" = 0 ] || die "needs root (network namespaces and slurmd)"
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
if [ -s "$dir/tag" ]; then net=$(cat "$dir/tag"); else net=""; fi
br="cabcbr$net"

stop_pidfile() {
  local f=$1 pid
  [ -f "$f" ] || return 0
  pid=$(cat "$f" 2>/dev/null || true)
  if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
    kill -TERM "$pid" 2>/dev/null || true
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
  fi
  rm -f "$f"
}

down() {
  # slurmd first (each stops its job steps' slurmstepd), then the controller, then munge.
  for f in "$dir"/slurmd-*.pid; do stop_pidfile "$f"; done
  # What is left of a job (a step whose slurmd is gone) lives in the nodes' namespaces: end it with them.
  for ns in $(ip netns list 2>/dev/null | awk '{print $1}' | grep "^cabc-$net-n" || true); do
    for pid in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$pid" 2>/dev/null || true; done
    ip netns del "$ns" 2>/dev/null || true
  done
  stop_pidfile "$dir/slurmctld.pid"
  stop_pidfile "$dir/munged.pid"
  ip link del "$br" 2>/dev/null || true
}

if [ "$cmd" = down ]; then
  [ -n "$net" ] && down
  rm -f "$dir/tag"
  say "stopped (cluster in $dir)"
  exit 0
fi

# --- up ---
[[ "$nodes" =~ ^[1-9][0-9]?$ ]] || die "NODES must be 1..99, not $nodes"
if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null || ! command -v sbatch >/dev/null \
   || ! command -v munged >/dev/null; then
  say "installing slurmctld slurmd slurm-client munge (apt-get)"
  install() {
    DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends slurmctld slurmd slurm-client munge \
      >> "$dir/apt.log" 2>&1
  }
  # Package lists that are missing or stale are fetched once.
  install || { apt-get update >> "$dir/apt.log" 2>&1 && install; } || die "apt-get install failed: $dir/apt.log"
fi
command -v ip >/dev/null || die "no 'ip' (iproute2)"
[ -n "$net" ] && down  # a leftover of an earlier cluster in the same folder
net=$(tag_of "$dir")
br="cabcbr$net"
echo "$net" > "$dir/tag"
# A cluster that does not come up is taken down again: nothing of it is left running.
trap 'down; rm -f "$dir/tag"' EXIT

mkdir -p "$dir/state" "$dir/spool" "$dir/log" "$dir/munge"
chmod 700 "$dir/munge"

# munge: a key of this cluster, a daemon of this cluster on its own socket.
if [ ! -s "$dir/munge/munge.key" ]; then
  head -c 128 /dev/urandom > "$dir/munge/munge.key"
  chmod 600 "$dir/munge/munge.key"
fi
[ -S "$dir/munge/munge.sock" ] && rm -f "$dir/munge/munge.sock"
munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.sock" \
  --pid-file="$dir/munged.pid" --log-file="$dir/log/munged.log" --seed-file="$dir/munge/munge.seed" \
  || die "munged did not start: $dir/log/munged.log"

# The network: a bridge with the controller's address, a namespace per node on it.
ctl="10.201.$net.254"
ip link add "$br" type bridge
ip addr add "$ctl/24" dev "$br"
ip link set "$br" up
for k in $(seq "$nodes"); do
  ns="cabc-$net-n$k"
  ip netns add "$ns"
  ip -n "$ns" link set lo up
  ip link add "c${net}n${k}h" type veth peer name "c${net}n${k}" netns "$ns"
  ip link set "c${net}n${k}h" master "$br" up
  ip -n "$ns" addr add "10.201.$net.$k/24" dev "c${net}n${k}"
  ip -n "$ns" link set "c${net}n${k}" up
done

cpus=$(nproc)
mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 / 2 ))
host=$(hostname -s)
{
  echo "# Written by deploy/slurm/cluster.sh: $nodes nodes on this machine, each in its own network namespace."
  echo "ClusterName=cabc$net"
  echo "SlurmctldHost=$host($ctl)"
  echo "SlurmctldPort=$((6800 + net * 2))"
  echo "SlurmdPort=6818"
  echo "AuthType=auth/munge"
  echo "CredType=cred/munge"
  echo "AuthInfo=socket=$dir/munge/munge.sock"
  echo "SlurmUser=root"
  echo "SlurmdUser=root"
  echo "StateSaveLocation=$dir/state"
  echo "SlurmdSpoolDir=$dir/spool/%n"
  echo "SlurmctldPidFile=$dir/slurmctld.pid"
  echo "SlurmdPidFile=$dir/slurmd-%n.pid"
  echo "SlurmctldLogFile=$dir/log/slurmctld.log"
  echo "SlurmdLogFile=$dir/log/slurmd-%n.log"
  echo "ProctrackType=proctrack/linuxproc"
  echo "TaskPlugin=task/none"
  echo "JobAcctGatherType=jobacct_gather/none"
  echo "AccountingStorageType=accounting_storage/none"
  echo "JobCompType=jobcomp/none"
  echo "SchedulerType=sched/backfill"
  echo "SelectType=select/cons_tres"
  echo "SelectTypeParameters=CR_Core"
  echo "MpiDefault=none"
  echo "ReturnToService=2"
  echo "SlurmctldTimeout=30"
  echo "SlurmdTimeout=60"
  echo "KillWait=${CABC_SLURM_KILLWAIT:-30}"
  echo "MinJobAge=300"
  echo "JobRequeue=1"
  for k in $(seq "$nodes"); do
    echo "NodeName=n$k NodeAddr=10.201.$net.$k NodeHostname=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN"
  done
  echo "PartitionName=cabc Nodes=n[1-$nodes] Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO"
} > "$dir/slurm.conf"
# slurmd initialises a cgroup plugin even under proctrack/linuxproc; name the hierarchy this machine mounts (its
# autodetection takes a tmpfs /sys/fs/cgroup with v1 controllers under it for none).
if [ -d /sys/fs/cgroup/unified ] || [ -d /sys/fs/cgroup/cpu ]; then cgroup=cgroup/v1; else cgroup=autodetect; fi
# Without systemd (a container, a CI machine) the cgroup/v2 plugin must not ask it for a scope.
printf 'CgroupPlugin=%s\nCgroupMountpoint=/sys/fs/cgroup\nIgnoreSystemd=yes\n' "$cgroup" > "$dir/cgroup.conf"

slurmctld -f "$dir/slurm.conf" -i >> "$dir/log/slurmctld.out" 2>&1 || die "slurmctld did not start: $dir/log/slurmctld.log"
for k in $(seq "$nodes"); do
  mkdir -p "$dir/spool/n$k"
  ip netns exec "cabc-$net-n$k" slurmd -f "$dir/slurm.conf" -N "n$k" >> "$dir/log/slurmd-n$k.out" 2>&1 \
    || die "slurmd n$k did not start: $dir/log/slurmd-n$k.log"
done

export SLURM_CONF="$dir/slurm.conf"
for _ in $(seq 120); do
  idle=$(sinfo -h -N -o '%N %t' 2>/dev/null | awk '$2 == "idle"' | wc -l)
  [ "$idle" = "$nodes" ] && { trap - EXIT; say "up: $nodes nodes idle (SLURM_CONF=$SLURM_CONF)"; exit 0; }
  sleep 0.5
done
sinfo -N >&2 || true
die "the nodes did not come up idle in 60 s: $dir/log/"
