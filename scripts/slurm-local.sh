#!/usr/bin/env bash
# A real single-node Slurm on this machine, for tests and trying `cgenreg slurm` out:
# munged + slurmctld + slurmd (Debian 12 packages slurm-wlm and munge, Slurm 22.05) with a
# minimal slurm.conf, everything (config, state, spool, logs, pid files, the munge socket) in
# one folder, on non-default ports so it never meets a system Slurm.
#
#   bash scripts/slurm-local.sh start DIR   # prints `export SLURM_CONF=DIR/slurm.conf` on success
#   bash scripts/slurm-local.sh stop DIR    # stops the three daemons by their pid files
#
# Ports: $CGENREG_SLURM_CTLD_PORT / $CGENREG_SLURM_D_PORT (default 16817 / 16818). Needs root
# (slurmd launches the jobs). Exit status 2 with a reason on stderr when it cannot start.
set -euo pipefail

cmd="${1:-}"
dir="${2:-}"
if [ -z "$cmd" ] || [ -z "$dir" ]; then
  echo "usage: $0 start|stop DIR" >&2
  exit 2
fi

fail() {
  echo "slurm-local: $*" >&2
  exit 2
}

stop_pid() {
  local f="$1"
  [ -f "$f" ] || return 0
  local p
  p="$(cat "$f" 2>/dev/null || true)"
  if [ -n "$p" ] && kill -0 "$p" 2>/dev/null; then
    kill "$p" 2>/dev/null || true
    for _ in $(seq 1 50); do
      kill -0 "$p" 2>/dev/null || break
      sleep 0.1
    done
    kill -9 "$p" 2>/dev/null || true
  fi
  rm -f "$f"
}

case "$cmd" in
stop)
  stop_pid "$dir/slurmd.pid"
  stop_pid "$dir/slurmctld.pid"
  stop_pid "$dir/munged.pid"
  exit 0
  ;;
start) ;;
*) fail "unknown command $cmd (start|stop)" ;;
esac

for b in munged slurmctld slurmd sinfo sbatch; do
  command -v "$b" >/dev/null 2>&1 || fail "$b not found: install the Debian packages slurm-wlm and munge (scripts/setup.sh does)"
done
[ "$(id -u)" -eq 0 ] || fail "must run as root (slurmd starts the jobs as their user)"

mkdir -p "$dir"/{state,spool,log,munge}
dir="$(cd "$dir" && pwd)"
host="$(hostname -s)"
cpus="$(nproc)"
mem_mb=$(($(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 * 8 / 10))
ctld_port="${CGENREG_SLURM_CTLD_PORT:-16817}"
d_port="${CGENREG_SLURM_D_PORT:-16818}"

# munge: its own key, socket and pid file (the system's munged, if any, is left alone).
key="$dir/munge/munge.key"
if [ ! -f "$key" ]; then
  head -c 1024 /dev/urandom >"$key"
fi
chown -R munge:munge "$dir/munge" 2>/dev/null || true
chmod 700 "$dir/munge"
chmod 400 "$key"
sock="$dir/munge/munge.socket"
if ! munged --socket="$sock" --key-file="$key" --pid-file="$dir/munged.pid" \
  --log-file="$dir/log/munged.log" --seed-file="$dir/munge/munge.seed" --force 2>"$dir/log/munged.err"; then
  fail "munged did not start: $(tail -3 "$dir/log/munged.err" "$dir/log/munged.log" 2>/dev/null | tr '\n' ' ')"
fi

cat >"$dir/slurm.conf" <<EOF
ClusterName=cgenreg-local
SlurmctldHost=$host
SlurmUser=root
SlurmctldPort=$ctld_port
SlurmdPort=$d_port
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$sock
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
ReturnToService=2
MpiDefault=none
SchedulerType=sched/backfill
SchedulerParameters=sched_interval=1
KillWait=5
InactiveLimit=0
MinJobAge=300
NodeName=$host CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF

export SLURM_CONF="$dir/slurm.conf"
slurmctld -f "$SLURM_CONF" 2>"$dir/log/slurmctld.err" ||
  fail "slurmctld did not start: $(tail -5 "$dir/log/slurmctld.err" "$dir/log/slurmctld.log" 2>/dev/null | tr '\n' ' ')"
slurmd -f "$SLURM_CONF" 2>"$dir/log/slurmd.err" ||
  fail "slurmd did not start: $(tail -5 "$dir/log/slurmd.err" "$dir/log/slurmd.log" 2>/dev/null | tr '\n' ' ')"

# Wait (at most 30 s) for the node to be schedulable.
for _ in $(seq 1 60); do
  state="$(sinfo -h -N -o '%t' 2>/dev/null | head -1 || true)"
  case "$state" in
  idle* | mix* | alloc*)
    echo "export SLURM_CONF=$SLURM_CONF"
    exit 0
    ;;
  esac
  sleep 0.5
done
fail "node not idle after 30 s (state '${state:-none}'): $(tail -5 "$dir/log/slurmctld.log" "$dir/log/slurmd.log" 2>/dev/null | tr '\n' ' ')"
