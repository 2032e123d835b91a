#!/usr/bin/env bash
# A single-host Slurm cluster for tests and trials: munged + slurmctld + slurmd on this machine, as root, without
# systemd, every file (config, munge key and socket, state, spool, logs, pid files) under one directory.
#
# Usage: scripts/local-slurm.sh start DIR   configure and start the daemons, wait until the node is idle
#        scripts/local-slurm.sh stop DIR    stop the daemons started with DIR (by their pid files) and wait for them
# Then point Slurm's commands at the cluster: SLURM_CONF=DIR/slurm.conf sbatch ...
#
# Needs Debian's slurm-wlm and munge (scripts/setup.sh installs them). The node is this host (`slurmd -C`: its
# CPUs, sockets, cores and memory), one partition "local" that is the default; the controller and slurmd listen on
# two free loopback-reachable ports picked at start, so a system Slurm on the default ports is left alone. Jobs run
# as the submitting user (root here): process tracking by /proc (proctrack/linuxproc), no task binding (task/none),
# no cgroups, no accounting database. Cores are the consumable resource (select/cons_tres, CR_Core), so the tasks of
# a job array run side by side, one per core.
#
# Environment: LOCAL_SLURM_TIMEOUT seconds to wait for the node to turn idle (default 30).
# Exit status: 0 started (or stopped), 2 usage, 3 a daemon did not start or the node did not turn idle in time (its
# log is printed on stderr; whatever did start is stopped again).
set -euo pipefail

usage() {
  sed -n '4,6p' "${BASH_SOURCE[0]}" | sed 's/^# //' >&2
  exit 2
}
[ $# -eq 2 ] || usage
ACTION=$1
DIR=$2
case $ACTION in start | stop) ;; *) usage ;; esac
PIDS=(slurmd slurmctld munged) # stop order; start is the reverse

pid_of() { cat "$DIR/$1.pid" 2>/dev/null || true; }

stop_all() {
  local name pid
  # Jobs first, so that no slurmstepd or job process outlives the daemons (every job of this cluster is ours).
  pid=$(pid_of slurmctld)
  if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null && [ -f "$DIR/slurm.conf" ]; then
    SLURM_CONF=$DIR/slurm.conf scancel --full --user="$(id -un)" 2>/dev/null || true
    for _ in $(seq 1 50); do
      [ -z "$(SLURM_CONF=$DIR/slurm.conf squeue --noheader 2>/dev/null)" ] && break
      sleep 0.2
    done
  fi
  for name in "${PIDS[@]}"; do
    pid=$(pid_of "$name")
    [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null || continue
    kill -TERM "$pid" 2>/dev/null || true
    for _ in $(seq 1 100); do
      kill -0 "$pid" 2>/dev/null || break
      sleep 0.1
    done
    kill -0 "$pid" 2>/dev/null && kill -KILL "$pid" 2>/dev/null || true
    rm -f "$DIR/$name.pid"
  done
}

if [ "$ACTION" = stop ]; then
  stop_all
  exit 0
fi

fail() {
  echo "local-slurm: $1" >&2
  local log
  for log in "${@:2}"; do
    [ -f "$log" ] && { echo "--- $log (last 40 lines)" >&2; tail -n 40 "$log" >&2; }
  done
  stop_all
  exit 3
}

[ "$(id -u)" -eq 0 ] || { echo "local-slurm: must run as root (slurmd starts jobs as their users)" >&2; exit 3; }
for tool in munged mungekey slurmctld slurmd sinfo python3; do
  command -v "$tool" >/dev/null || PATH=$PATH:/usr/sbin
  command -v "$tool" >/dev/null || fail "$tool not found: install slurm-wlm and munge (scripts/setup.sh)"
done

mkdir -p "$DIR"
DIR=$(cd "$DIR" && pwd)
mkdir -p "$DIR/munge" "$DIR/run" "$DIR/state" "$DIR/spool"
# munged wants its key private and every directory above its socket searchable by all (clients of any user).
chmod 700 "$DIR/munge"
chmod 755 "$DIR" "$DIR/run"
[ -f "$DIR/munge/munge.key" ] || mungekey --create --keyfile="$DIR/munge/munge.key"
SOCKET=$DIR/run/munge.socket.2
munged --socket="$SOCKET" --key-file="$DIR/munge/munge.key" --pid-file="$DIR/munged.pid" \
  --log-file="$DIR/munged.log" --seed-file="$DIR/munge/munged.seed" >>"$DIR/munged.log" 2>&1 ||
  fail "munged did not start" "$DIR/munged.log"

# The node as slurmd sees it ("NodeName=host CPUs=2 Boards=1 SocketsPerBoard=1 ... RealMemory=24105").
NODE=$(slurmd -C | head -n 1)
[[ $NODE =~ ^NodeName=([^ ]+)\  ]] || fail "slurmd -C printed no node line: $NODE"
HOST=${BASH_REMATCH[1]}
read -r CTLD_PORT SLURMD_PORT < <(python3 -c '
import socket
sockets = [socket.socket() for _ in range(2)]
for s in sockets:
    s.bind(("127.0.0.1", 0))
print(*(s.getsockname()[1] for s in sockets))')

cat >"$DIR/slurm.conf" <<EOF
# Written by scripts/local-slurm.sh: a one-node cluster on this host.
ClusterName=surfacer-local
SlurmctldHost=$HOST(127.0.0.1)
SlurmctldPort=$CTLD_PORT
SlurmdPort=$SLURMD_PORT
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$SOCKET
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/slurmctld.log
SlurmdLogFile=$DIR/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SwitchType=switch/none
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
ReturnToService=2
SchedulerType=sched/backfill
$NODE NodeAddr=127.0.0.1 State=UNKNOWN
PartitionName=local Nodes=$HOST Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF=$DIR/slurm.conf

slurmctld -f "$SLURM_CONF" -i >>"$DIR/slurmctld.log" 2>&1 || fail "slurmctld did not start" "$DIR/slurmctld.log"
slurmd -f "$SLURM_CONF" >>"$DIR/slurmd.log" 2>&1 || fail "slurmd did not start" "$DIR/slurmd.log"

TIMEOUT=${LOCAL_SLURM_TIMEOUT:-30}
deadline=$((SECONDS + TIMEOUT))
state=""
while [ "$SECONDS" -lt "$deadline" ]; do
  state=$(sinfo --noheader --nodes="$HOST" --format=%T 2>/dev/null || true)
  [ "$state" = idle ] && { echo "local-slurm: node $HOST idle (SLURM_CONF=$SLURM_CONF)"; exit 0; }
  sleep 0.5
done
fail "node $HOST not idle after $TIMEOUT s (state: ${state:-no answer from slurmctld})" \
  "$DIR/munged.log" "$DIR/slurmctld.log" "$DIR/slurmd.log"
