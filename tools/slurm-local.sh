#!/usr/bin/env bash
# A one-node Slurm cluster on localhost, for trying `nimbus farm` and for its tests.
#
#   tools/slurm-local.sh start DIR   start munged, slurmctld and slurmd; everything under DIR
#   tools/slurm-local.sh stop DIR    stop exactly the daemons that `start DIR` started
#   tools/slurm-local.sh env DIR     print the export line clients need (SLURM_CONF=DIR/slurm.conf)
#
# Needs root (slurmd runs jobs as their submitting user) and `tools/setup.sh --farm`.
# It uses its own munge socket, key copy and slurm.conf under DIR, so it neither uses nor
# disturbs a munged or Slurm already on the machine. After `start`, run clients as
#   export SLURM_CONF=DIR/slurm.conf; sinfo; nimbus farm submit ...
# `start` waits until the node is idle (about 3 s) and exits non-zero, with the daemon logs'
# tails, if it does not get there.
set -euo pipefail

usage() {
  sed -n '2,13p' "$0" | sed 's/^# \{0,1\}//' >&2
  exit 2
}
[[ $# -eq 2 ]] || usage
cmd=$1
dir=$(mkdir -p "$2" && cd "$2" && pwd)
conf=$dir/slurm.conf

# The pids a start wrote; stop kills only these (and only if they still run the same program).
stop_pid() { # pidfile program
  local f=$1 prog=$2 pid
  [[ -s $f ]] || return 0
  pid=$(cat "$f")
  if [[ -r /proc/$pid/comm ]] && [[ $(cat /proc/$pid/comm) == "$prog" ]]; then
    kill -TERM "$pid" 2>/dev/null || true
    for _ in $(seq 50); do
      [[ -d /proc/$pid ]] || break
      sleep 0.1
    done
    if [[ -d /proc/$pid ]]; then kill -KILL "$pid" 2>/dev/null || true; fi
  fi
  rm -f "$f"
}

stop() {
  stop_pid "$dir/slurmd.pid" slurmd
  stop_pid "$dir/slurmctld.pid" slurmctld
  stop_pid "$dir/munge/munged.pid" munged
}

start() {
  for prog in munged slurmctld slurmd sbatch; do
    command -v "$prog" >/dev/null || {
      echo "slurm-local: $prog not found: run tools/setup.sh --farm" >&2
      exit 3
    }
  done
  [[ $(id -u) -eq 0 ]] || {
    echo "slurm-local: must run as root (slurmd starts jobs as their user)" >&2
    exit 3
  }
  if [[ -s $dir/slurmctld.pid ]] && [[ -d /proc/$(cat "$dir/slurmctld.pid") ]]; then
    echo "slurm-local: already running in $dir (stop it with: $0 stop $dir)" >&2
    exit 3
  fi
  mkdir -p "$dir/state" "$dir/spool" "$dir/munge"
  # munged refuses a socket directory others may write to, or a key others may read.
  chown munge:munge "$dir/munge"
  chmod 0755 "$dir/munge"
  if [[ ! -s $dir/munge/munge.key ]]; then
    if [[ -s /etc/munge/munge.key ]]; then
      cp /etc/munge/munge.key "$dir/munge/munge.key"
    else
      dd if=/dev/urandom of="$dir/munge/munge.key" bs=1024 count=1 status=none
    fi
  fi
  chown munge:munge "$dir/munge/munge.key"
  chmod 0400 "$dir/munge/munge.key"
  local sock=$dir/munge/munge.socket
  su -s /bin/sh munge -c "/usr/sbin/munged --socket=$sock --key-file=$dir/munge/munge.key \
    --pid-file=$dir/munge/munged.pid --log-file=$dir/munge/munged.log \
    --seed-file=$dir/munge/munged.seed"
  local cpus mem
  cpus=$(nproc)
  mem=$(($(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 / 2))
  cat >"$conf" <<EOF
# Written by tools/slurm-local.sh: a one-node cluster on localhost, every path under $dir.
ClusterName=nimbus-local
SlurmctldHost=localhost
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
# cred_expire also sets how long a requeued job waits before it may start again (default 120 s).
AuthInfo=socket=$sock,cred_expire=10
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
SlurmctldPort=${NIMBUS_SLURM_PORT:-6817}
SlurmdPort=$((${NIMBUS_SLURM_PORT:-6817} + 1))
ReturnToService=2
MpiDefault=none
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
# Short timers: a test cluster should schedule quickly (sched_interval: the main scheduler loop,
# which starts a requeued job once its BeginTime has passed; default 60 s).
SchedulerParameters=bf_interval=1,sched_interval=2,sched_min_interval=200000
MinJobAge=600
KillWait=5
InactiveLimit=0
NodeName=localhost CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=main Nodes=localhost Default=YES MaxTime=INFINITE State=UP OverSubscribe=YES
EOF
  SLURM_CONF=$conf slurmctld -f "$conf"
  SLURM_CONF=$conf slurmd -f "$conf"
  for _ in $(seq 100); do
    if SLURM_CONF=$conf sinfo -h -o '%t' 2>/dev/null | grep -qx idle; then
      echo "slurm-local: cluster up in $dir; clients: export SLURM_CONF=$conf" >&2
      return 0
    fi
    sleep 0.2
  done
  echo "slurm-local: the node did not become idle within 20 s; logs:" >&2
  tail -n 20 "$dir/slurmctld.log" "$dir/slurmd.log" >&2 || true
  stop
  exit 3
}

case $cmd in
start) start ;;
stop) stop ;;
env) echo "export SLURM_CONF=$conf" ;;
*) usage ;;
esac
