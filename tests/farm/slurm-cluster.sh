#!/usr/bin/env bash
# A single-node Slurm cluster for trying `stereogen farm slurm` (and for tests/integration/farm_slurm.rs):
# munged, slurmctld and slurmd from Debian's packages, started directly (no systemd), with every
# file under one directory.
#
#   tests/farm/slurm-cluster.sh start DIR   # prints `export SLURM_CONF=DIR/slurm.conf`
#   SLURM_CONF=DIR/slurm.conf sbatch ...    # submit, squeue, scancel as usual
#   tests/farm/slurm-cluster.sh stop DIR    # stops the three daemons (by their pid files)
#
# Needs root (slurmd runs jobs as their owner) and `apt-get install -y slurm-wlm munge`; with
# STEREOGEN_INSTALL_SLURM=1 `start` installs them when missing. Ports come from
# STEREOGEN_SLURM_PORT (default 16817; slurmd uses the next one).
set -euo pipefail

usage() { echo "usage: $0 start|stop DIR" >&2; exit 2; }
[ $# -eq 2 ] || usage
action=$1
dir=$(mkdir -p "$2" && cd "$2" && pwd)

stop() {
  # Jobs first (their steps are slurmd's children only in name: slurmstepd outlives slurmd), then
  # slurmd, the controller and munge.
  if [ -s "$dir/slurmctld.pid" ] && kill -0 "$(cat "$dir/slurmctld.pid")" 2>/dev/null; then
    export SLURM_CONF="$dir/slurm.conf"
    jobs=$(squeue -h -o %A 2>/dev/null | sort -u | tr '\n' ' ')
    if [ -n "${jobs// }" ]; then
      # shellcheck disable=SC2086
      scancel --full $jobs 2>/dev/null || true
      for _ in $(seq 150); do [ -z "$(squeue -h -o %A 2>/dev/null)" ] && break; sleep 0.2; done
    fi
  fi
  for name in slurmd slurmctld munged; do
    pidfile="$dir/$name.pid"
    [ -s "$pidfile" ] || continue
    pid=$(cat "$pidfile")
    if kill -0 "$pid" 2>/dev/null; then
      kill -TERM "$pid" 2>/dev/null || true
      for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
      kill -0 "$pid" 2>/dev/null && kill -KILL "$pid" 2>/dev/null || true
    fi
    rm -f "$pidfile"
  done
}

install_if_missing() {
  command -v slurmctld >/dev/null && command -v munged >/dev/null && return 0
  if [ "${STEREOGEN_INSTALL_SLURM:-0}" = 1 ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "installing slurm-wlm and munge with apt-get" >&2
    DEBIAN_FRONTEND=noninteractive apt-get install -y slurm-wlm munge >&2 || {
      apt-get update >&2 && DEBIAN_FRONTEND=noninteractive apt-get install -y slurm-wlm munge >&2
    }
  fi
  command -v slurmctld >/dev/null && command -v munged >/dev/null || {
    echo "slurm-cluster: slurmctld/munged not found; install them: apt-get install -y slurm-wlm munge" >&2
    exit 3
  }
}

start() {
  [ "$(id -u)" = 0 ] || { echo "slurm-cluster: must run as root (slurmd starts jobs as their user)" >&2; exit 3; }
  install_if_missing
  stop
  local port=${STEREOGEN_SLURM_PORT:-16817}
  local host
  host=$(hostname -s)
  mkdir -p "$dir/munge" "$dir/state" "$dir/spool" "$dir/log"
  chmod 700 "$dir/munge"
  # A fresh key for this cluster only.
  head -c 1024 /dev/urandom > "$dir/munge/munge.key"
  chmod 400 "$dir/munge/munge.key"
  munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
    --pid-file="$dir/munged.pid" --log-file="$dir/log/munged.log" --seed-file="$dir/munge/munge.seed"
  # The node as slurmd sees this machine (CPUs, sockets, memory), less the UpTime line.
  local node
  node=$(slurmd -C | head -n 1)
  cat > "$dir/slurm.conf" <<CONF
# Written by tests/farm/slurm-cluster.sh: a one-node cluster under $dir.
ClusterName=stereogen-test
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
SlurmctldPort=$port
SlurmdPort=$((port + 1))
AuthType=auth/munge
# cred_expire: a job step's credential lifetime, and how long a requeued job waits before it may
# start again (Slurm's default 120 s; the training requeue test sat idle for it).
AuthInfo=socket=$dir/munge/munge.socket,cred_expire=30
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
ReturnToService=2
# A cancelled step gets SIGTERM, then SIGKILL this many seconds later.
KillWait=10
# Finished jobs stay visible to squeue/scontrol for a while; dependencies resolve quickly.
MinJobAge=300
SchedulerParameters=sched_min_interval=100000
$node State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
  export SLURM_CONF="$dir/slurm.conf"
  slurmctld -f "$SLURM_CONF"
  slurmd -f "$SLURM_CONF"
  # Ready when the node is idle.
  for _ in $(seq 100); do
    if sinfo -h -o %t 2>/dev/null | grep -q idle; then
      echo "export SLURM_CONF=$SLURM_CONF"
      return 0
    fi
    sleep 0.2
  done
  echo "slurm-cluster: the node did not become idle; logs in $dir/log" >&2
  sinfo >&2 || true
  tail -n 20 "$dir/log/slurmctld.log" "$dir/log/slurmd.log" >&2 || true
  exit 4
}

case $action in
  start) start ;;
  stop) stop ;;
  *) usage ;;
esac
