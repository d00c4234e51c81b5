#!/bin/bash
# Starts a Slurm on this machine for the tests (tests/slurm/daemons.rs): munged, slurmctld and slurmd,
# listening on this host only, with every file under the state directory given as $1 and no
# accounting database (so `sacct` does not work; `squeue` does). When `sbatch` is missing
# and we are root with apt-get, installs Debian's slurm-wlm and munge first.
#
# The ports are $SLURMCTLD_PORT and $SLURMD_PORT (default 16817 and 16818: off Slurm's own
# defaults, so a site Slurm on this machine is not disturbed). With $SLURM_NODES above 1, the
# machine plays that many nodes, pg1, pg2, ..., each served by a slurmd of its own (`slurmd -N`,
# slurmd's multiple-slurmd mode) on ports from $SLURMD_PORT up, one CPU each.
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
# the second is its uptime). Cut in the shell: `| head -n 1` could end slurmd with SIGPIPE,
# which pipefail reports as a failure.
node=$(slurmd -C)
node=${node%%$'\n'*}
case $node in
    NodeName=*) ;;
    *) echo "slurmd -C did not describe the node: $node" >&2; exit 1 ;;
esac
nodes=${SLURM_NODES:-1}
slurmd_port=${SLURMD_PORT:-16818}
if [ "$nodes" -gt 1 ]; then
    names=$(seq -s, -f "pg%g" 1 "$nodes")
    node_lines=$(for i in $(seq 1 "$nodes"); do
        echo "NodeName=pg$i NodeHostname=$host NodeAddr=127.0.0.1 Port=$((slurmd_port + i - 1)) CPUs=1 State=UNKNOWN"
    done)
    daemon_files="SlurmdSpoolDir=$state/slurmd-%n
SlurmdPidFile=$state/slurmd-%n.pid
SlurmdLogFile=$state/slurmd-%n.log"
else
    names=$host
    node_lines="$node NodeAddr=127.0.0.1 State=UNKNOWN"
    daemon_files="SlurmdPort=$slurmd_port
SlurmdSpoolDir=$state/slurmd
SlurmdPidFile=$state/slurmd.pid
SlurmdLogFile=$state/slurmd.log"
fi
cat >"$state/slurm.conf" <<EOF
ClusterName=pushgrasp-test
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=${SLURMCTLD_PORT:-16817}
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$socket
StateSaveLocation=$state/slurmctld
SlurmctldPidFile=$state/slurmctld.pid
SlurmctldLogFile=$state/slurmctld.log
$daemon_files
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
$node_lines
PartitionName=test Nodes=$names Default=YES MaxTime=INFINITE State=UP
EOF
mkdir -p "$state/slurmctld" "$state/slurmd"
export SLURM_CONF="$state/slurm.conf"

# -i: ignore state from an earlier start in the same directory.
slurmctld -i -f "$SLURM_CONF"
if [ "$nodes" -gt 1 ]; then
    slurmd_pids=()
    for i in $(seq 1 "$nodes"); do
        slurmd -f "$SLURM_CONF" -N "pg$i"
        slurmd_pids+=("$state/slurmd-pg$i.pid")
    done
else
    slurmd -f "$SLURM_CONF"
    slurmd_pids=("$state/slurmd.pid")
fi
for _ in $(seq 50); do
    ready=yes
    for pid in "$state/slurmctld.pid" "${slurmd_pids[@]}"; do
        [ -s "$pid" ] || ready=no
    done
    [ $ready = yes ] && break
    sleep 0.2
done
cat "$state/slurmctld.pid" "${slurmd_pids[@]}" >>"$state/pids" 2>/dev/null || true

# The nodes are usable once slurmctld has heard from each slurmd and calls it idle.
for _ in $(seq 100); do
    if [ "$(sinfo -h -N -o %t 2>/dev/null | grep -cx idle)" -ge "$nodes" ]; then
        echo "SLURM_CONF=$SLURM_CONF"
        exit 0
    fi
    sleep 0.3
done
echo "the Slurm nodes did not become idle within 30 s: sinfo says" \
    "$(sinfo -h -N -o '%t %E' 2>&1 | tr '\n' ' ')" >&2
tail -n 5 "$state"/slurmctld.log "$state"/slurmd*.log >&2 2>/dev/null || true
exit 1
