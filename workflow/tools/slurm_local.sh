#!/usr/bin/env bash
# A real one-node SLURM cluster on this machine, to try workflow/profiles/slurm without a cluster
# (and for tests/test_slurm.py). Needs Debian/Ubuntu's packages: sudo apt-get install slurm-wlm munge
#
#   eval "$(workflow/tools/slurm_local.sh start)"  # start it (or find it running); sets SLURM_CONF, PATH
#   workflow/tools/slurm_local.sh status           # sinfo + squeue; exit 0 when the node is up
#   workflow/tools/slurm_local.sh stop             # stop the daemons this script started
#   workflow/tools/slurm_local.sh env              # print the export line only
#
# Everything (munge key and socket, slurm.conf, state, logs) lives in one folder (no spaces in its
# path): the second argument, else $SPC3D_SLURM_DIR, else ${TMPDIR:-/tmp}/spc3d-slurm-$USER.
# One node with this machine's CPUs and memory (`slurmd -C`), partition `local` (the default).
# No systemd, cgroups or slurmdbd: processes are tracked through /proc (proctrack/linuxproc,
# task/none), so memory and CPU requests are scheduled but not enforced; finished jobs stay
# visible to `squeue` for an hour (MinJobAge), which is how Snakemake's SLURM executor follows
# them here (`sacct` needs slurmdbd). Ports: $SPC3D_SLURM_PORT (default 6817) for slurmctld and
# the next one for slurmd. Run it as root, or as yourself: the daemons then run as you and only
# your jobs can run.
#
# Clients find the cluster through SLURM_CONF. Snakemake's jobstep plugin removes SLURM_* variables
# before the `srun` it runs inside each job, so bin/srun here (put first on PATH) sets it again.
set -euo pipefail

usage() { echo "usage: $0 start|stop|status|env [folder]" >&2; exit 2; }
[[ $# -ge 1 && $# -le 2 ]] || usage
ACTION=$1
DIR=${2:-${SPC3D_SLURM_DIR:-${TMPDIR:-/tmp}/spc3d-slurm-$(id -un)}}
mkdir -p "$DIR"
DIR=$(cd "$DIR" && pwd)
CONF=$DIR/slurm.conf
SOCKET=$DIR/munge/munge.socket
PORT=${SPC3D_SLURM_PORT:-6817}
NODE=$(hostname -s)
export SLURM_CONF=$CONF PATH=$PATH:/usr/sbin:/sbin  # the daemons live in sbin

say() { echo "slurm_local: $*" >&2; }

need() {
    local missing=()
    for tool in munged munge slurmctld slurmd sbatch srun squeue sinfo scontrol; do
        command -v "$tool" >/dev/null || missing+=("$tool")
    done
    if [[ ${#missing[@]} -gt 0 ]]; then
        say "not installed: ${missing[*]} (Debian/Ubuntu: sudo apt-get install slurm-wlm munge)"
        exit 3
    fi
}

# pid from a pid file if that process is alive and is `name` (a zombie or a reused pid is not).
alive() {
    local pidfile=$1 name=$2 pid state
    # The daemon removes its pid file as it exits, so the file can vanish between any two lines here;
    # read it with `cat`: a failed `$(<file)` ends a `set -e` script even inside `||` (bash 5.2).
    pid=$(cat "$pidfile" 2>/dev/null) || return 1
    [[ $pid =~ ^[0-9]+$ ]] || return 1
    [[ -r /proc/$pid/stat ]] || return 1
    state=$(awk '{print $3}' "/proc/$pid/stat" 2>/dev/null) || return 1
    [[ $state != Z && $(cat "/proc/$pid/comm" 2>/dev/null) == "$name"* ]] || return 1
    echo "$pid"
}

munge_ok() { munge -S "$SOCKET" -n 2>/dev/null | unmunge -S "$SOCKET" >/dev/null 2>&1; }
node_state() { sinfo -h -N -n "$NODE" -o %T 2>/dev/null | head -1; }
node_up() { [[ $(node_state) =~ ^(idle|mixed|allocated|completing)$ ]]; }

write_conf() {
    local me hw srun
    me=$(id -un)
    # "NodeName=host CPUs=2 Boards=1 SocketsPerBoard=1 CoresPerSocket=2 ThreadsPerCore=1 RealMemory=24105"
    hw=$(slurmd -C | head -1 | sed 's/^NodeName=[^ ]* //')
    cat > "$CONF.new" <<EOF
# Written by workflow/tools/slurm_local.sh: a one-node cluster on $NODE, state and logs in $DIR.
ClusterName=spc3d-local
SlurmctldHost=$NODE(127.0.0.1)
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
SlurmUser=$me
SlurmdUser=$me
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$SOCKET
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/slurmctld.log
SlurmdLogFile=$DIR/slurmd.log
# No systemd or cgroups needed: processes tracked through /proc, no CPU binding.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
MpiDefault=none
# No slurmdbd: every finished job is appended to jobcomp.txt, and squeue shows it for an hour.
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$DIR/jobcomp.txt
MinJobAge=3600
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
KillWait=5
NodeName=$NODE NodeAddr=127.0.0.1 $hw State=UNKNOWN
PartitionName=local Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF
    mkdir -p "$DIR/bin"
    srun=$(PATH=${PATH//"$DIR/bin:"/} command -v srun)
    printf '#!/bin/sh\nSLURM_CONF=%q exec %q "$@"\n' "$CONF" "$srun" > "$DIR/bin/srun"
    chmod 0755 "$DIR/bin/srun"
    if cmp -s "$CONF.new" "$CONF"; then
        rm "$CONF.new"
    else
        stop_daemons  # a changed node or port: the daemons must read the new file
        mv "$CONF.new" "$CONF"
    fi
}

start_munge() {
    munge_ok && return
    mkdir -p "$DIR/munge"
    chmod 0755 "$DIR" "$DIR/munge"  # munged wants its socket folder reachable by every user
    if [[ ! -s $DIR/munge/munge.key ]]; then
        (umask 077 && dd if=/dev/urandom of="$DIR/munge/munge.key" bs=1024 count=1 2>/dev/null)
    fi
    chmod 0400 "$DIR/munge/munge.key"
    munged --force --socket="$SOCKET" --key-file="$DIR/munge/munge.key" --pid-file="$DIR/munge/munged.pid" \
        --log-file="$DIR/munge/munged.log" --seed-file="$DIR/munge/munged.seed" 9>&-
    for _ in $(seq 50); do munge_ok && return; sleep 0.1; done
    say "munged did not start; see $DIR/munge/munged.log"; tail -5 "$DIR/munge/munged.log" >&2; exit 1
}

start() {
    need
    write_conf
    start_munge
    mkdir -p "$DIR/state" "$DIR/spool"
    alive "$DIR/slurmctld.pid" slurmctld >/dev/null || slurmctld -f "$CONF" 9>&-  # 9>&-: daemons must not keep the lock
    for _ in $(seq 100); do scontrol ping >/dev/null 2>&1 && break; sleep 0.1; done
    alive "$DIR/slurmd.pid" slurmd >/dev/null || slurmd -f "$CONF" 9>&-
    for i in $(seq 300); do
        node_up && break
        # A node left down or drained by an earlier run comes back once its slurmd answers.
        if (( i % 20 == 0 )) && [[ $(node_state) =~ ^(down|drained|draining)$ ]]; then
            scontrol update NodeName="$NODE" State=RESUME >/dev/null 2>&1 || true
        fi
        sleep 0.1
    done
    if ! node_up; then
        say "node $NODE is '$(node_state)', not up; see $DIR/slurmctld.log and $DIR/slurmd.log"
        tail -5 "$DIR/slurmctld.log" "$DIR/slurmd.log" >&2 || true
        exit 1
    fi
    say "up: node $NODE ($(sinfo -h -N -n "$NODE" -o '%c CPUs, %m MB')), partition local, folder $DIR"
    exports
}

exports() { echo "export SLURM_CONF=$CONF PATH=$DIR/bin:\${PATH#$DIR/bin:}"; }

stop_one() {
    local pidfile=$1 name=$2 pid
    pid=$(alive "$pidfile" "$name") || return 0
    kill "$pid"
    for _ in $(seq 100); do alive "$pidfile" "$name" >/dev/null || return 0; sleep 0.1; done
    kill -9 "$pid" 2>/dev/null || true
}

stop_daemons() {
    stop_one "$DIR/slurmd.pid" slurmd
    stop_one "$DIR/slurmctld.pid" slurmctld
}

exec 9>"$DIR/.lock"
flock 9  # one start or stop at a time per folder
case $ACTION in
    start) start ;;
    stop)
        stop_daemons
        stop_one "$DIR/munge/munged.pid" munged
        say "stopped (state and logs stay in $DIR)" ;;
    status)
        need
        if munge_ok && node_up; then
            sinfo -N -o '%N %P %T %c %m' && squeue
        else
            say "not running (folder $DIR)"; exit 1
        fi ;;
    env) exports ;;
    *) usage ;;
esac
