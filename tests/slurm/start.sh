#!/bin/bash
# Starts a single-node Slurm on this machine for tests/sweep.rs: munged, slurmctld and slurmd,
# listening on this host only, with every file under the state directory given as $1 and no
# accounting database (so `sacct` does not work; `squeue` does). When `sbatch` is missing
# and we are root with apt-get, installs Debian's slurm-wlm and munge first.
#
# The ports are $SLURMCTLD_PORT and $SLURMD_PORT (default 16817 and 16818: off Slurm's own
# defaults, so a site Slurm on this machine is not disturbed).
#
# On success prints `SLURM_CONF=<file>` (the environment sbatch and squeue need) and leaves
# the daemons' pids in $1/pids, one a line, for the caller to stop. On failure prints why on
# stderr and exits non-zero; exit status 2 means Slurm cannot be had here at all.
set -euo pipefail

state=${1:?usage: start.sh STATE_DIR}
mkdir -p "$state"
state=$(cd "$state" && pwd)

if ! command -v sbatch >/dev/null; then
    if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null; then
        echo "sbatch is not on PATH, and installing it needs root and apt-get" >&2
        exit 2
    fi
    install() {
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
            slurm-wlm munge >>"$state/apt.log" 2>&1
    }
    # The package lists may be missing or stale; refresh them once if the first try fails.
    if ! install && ! { apt-get update -q >>"$state/apt.log" 2>&1 && install; }; then
        echo "apt-get could not install slurm-wlm and munge (see $state/apt.log):" >&2
        tail -n 5 "$state/apt.log" >&2
        exit 2
    fi
fi
for tool in munged slurmctld slurmd sbatch squeue; do
    command -v "$tool" >/dev/null || { echo "$tool is missing after the install" >&2; exit 2; }
done

# munge: a key and a socket of our own, so an existing munged is left alone.
mkdir -p "$state/munge"
chmod 700 "$state/munge"
if [ ! -e "$state/munge/munge.key" ]; then
    dd if=/dev/urandom of="$state/munge/munge.key" bs=1024 count=1 status=none
    chmod 400 "$state/munge/munge.key"
fi
socket="$state/munge/munge.socket"
munged --force \
    --key-file="$state/munge/munge.key" \
    --socket="$socket" \
    --pid-file="$state/munge/munged.pid" \
    --log-file="$state/munge/munged.log" \
    --seed-file="$state/munge/munged.seed"
cat "$state/munge/munged.pid" >"$state/pids"

host=$(hostname -s)
# slurmd -C describes this machine's hardware as slurm.conf wants it (first line only;
# the second is its uptime).
node=$(slurmd -C | head -n 1)
case $node in
    NodeName=*) ;;
    *) echo "slurmd -C did not describe the node: $node" >&2; exit 1 ;;
esac
cat >"$state/slurm.conf" <<EOF
ClusterName=pushgrasp-test
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=${SLURMCTLD_PORT:-16817}
SlurmdPort=${SLURMD_PORT:-16818}
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$socket
StateSaveLocation=$state/slurmctld
SlurmdSpoolDir=$state/slurmd
SlurmctldPidFile=$state/slurmctld.pid
SlurmdPidFile=$state/slurmd.pid
SlurmctldLogFile=$state/slurmctld.log
SlurmdLogFile=$state/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
$node NodeAddr=127.0.0.1 State=UNKNOWN
PartitionName=test Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
mkdir -p "$state/slurmctld" "$state/slurmd"
export SLURM_CONF="$state/slurm.conf"

# -i: ignore state from an earlier start in the same directory.
slurmctld -i -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"
for _ in $(seq 50); do
    [ -s "$state/slurmctld.pid" ] && [ -s "$state/slurmd.pid" ] && break
    sleep 0.2
done
cat "$state/slurmctld.pid" "$state/slurmd.pid" >>"$state/pids" 2>/dev/null || true

# The node is usable once slurmctld has heard from slurmd and calls it idle.
for _ in $(seq 100); do
    if sinfo -h -N -o %t 2>/dev/null | grep -qx idle; then
        echo "SLURM_CONF=$SLURM_CONF"
        exit 0
    fi
    sleep 0.3
done
echo "the Slurm node did not become idle within 30 s: sinfo says" \
    "$(sinfo -h -N -o '%t %E' 2>&1 | tr '\n' ' ')" >&2
tail -n 5 "$state/slurmctld.log" "$state/slurmd.log" >&2 2>/dev/null || true
exit 1
