#!/usr/bin/env bash
# A single-node SLURM on the loopback, as a test service: Debian 12's slurm 22.05
# packages and munge, run as root. tests/slurm_service.py starts and stops it for the slow test
# tests/test_slurm_service.py; docs/cluster.md says how to run that test.
#
#   bash tests/services/slurm.sh install     apt-get the four packages (Debian, as root)
#   bash tests/services/slurm.sh start DIR   write DIR/slurm.conf, start munged, slurmctld and slurmd
#                                            with every file under DIR, wait for the node to be idle,
#                                            print the export line a caller needs (SLURM_CONF=...)
#   bash tests/services/slurm.sh stop DIR    end the processes it started (their pid files in DIR), nothing else
#
# No accounting storage (no slurmdbd, no database): sacct has nothing to read, so submitit logs
# "Bypassing sacct error ..., status may be inaccurate." while it waits and sees a job finish by its
# result file; a job that dies without one is found through squeue (tests/slurm_service.py).
# SLURM_SERVICE_PORT (default 6817; slurmd takes the next port) moves the service off SLURM's
# default ports. munged is this service's own (its socket, pid, log and seed in DIR, a root-owned
# copy of the key the munge package made in /etc/munge), so a munged of the machine is neither used
# nor touched.
set -euo pipefail

PACKAGES=(slurmd slurmctld slurm-client munge)
NODE=localnode

die() { echo "slurm.sh: $*" >&2; exit 1; }

install_packages() {
    [ "$(id -u)" = 0 ] || die "install: run as root (apt-get)"
    DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${PACKAGES[@]}"
}

write_conf() {
    local dir=$1 port=${SLURM_SERVICE_PORT:-6817} cpus
    cpus=$(nproc)
    [ "$cpus" -gt 2 ] && cpus=2
    cat > "$dir/slurm.conf" <<EOF
ClusterName=testcluster
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge.socket
MpiDefault=none
MailProg=/bin/true
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
SchedulerType=sched/backfill
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
NodeName=$NODE NodeAddr=127.0.0.1 NodeHostname=localhost CPUs=$cpus RealMemory=1024 State=UNKNOWN
PartitionName=debug Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF
}

# wait_for SECONDS COMMAND...: run COMMAND every half second until it succeeds (1: it never did).
wait_for() {
    local seconds=$1 i
    shift
    for ((i = 0; i < seconds * 2; i++)); do
        "$@" >/dev/null 2>&1 && return 0
        sleep 0.5
    done
    return 1
}

# ours DIR NAME: the daemon NAME whose pid DIR/NAME.pid holds is running (that pid, that program)
ours() { [ -s "$1/$2.pid" ] && [ "$(cat "/proc/$(cat "$1/$2.pid")/comm" 2>/dev/null)" = "$2" ]; }

# launch DIR NAME ARGS...: start daemon NAME (it forks and writes DIR/NAME.pid) unless it runs
# already; its own output to DIR/NAME.out, never the caller's pipes; wait up to 20 s for its pid.
launch() {
    local dir=$1 name=$2
    shift 2
    ours "$dir" "$name" || "$name" "$@" </dev/null >>"$dir/$name.out" 2>&1 || true
    wait_for 20 ours "$dir" "$name" ||
        die "start: $name did not start ($(tail -n1 "$dir/$name.out" 2>/dev/null); see $dir/$name.log)"
}

node_idle() { [ "$(sinfo -h -n "$NODE" -o %t)" = idle ]; }

start() {
    local dir=$1 cmd p
    [ "$(id -u)" = 0 ] || die "start: run as root (SlurmUser=root, slurmd runs jobs as their user)"
    for cmd in munged slurmctld slurmd sinfo sbatch; do
        command -v "$cmd" >/dev/null || die "start: $cmd not found; install with: bash $0 install"
    done
    [ -r /etc/munge/munge.key ] || die "start: /etc/munge/munge.key missing (the munge package makes it)"
    mkdir -p "$dir/state" "$dir/spool"
    dir=$(cd "$dir" && pwd)
    # munged wants its socket's folder, and each above it, searchable by all (pytest's tmp_path is not)
    chmod 711 "$dir"
    local up=$dir
    while [ "$up" != / ]; do
        [ "$(( $(stat -c %#a "$up") & 1 ))" = 1 ] ||
            die "start: $up is not searchable by all (munged's socket needs that): choose a DIR elsewhere"
        up=$(dirname "$up")
    done
    [ ${#dir} -le 90 ] || die "start: $dir is too long for munge's socket path"
    local port=${SLURM_SERVICE_PORT:-6817}
    for p in "$port" "$((port + 1))"; do
        if (exec 3<>"/dev/tcp/127.0.0.1/$p") 2>/dev/null; then
            die "start: port $p of 127.0.0.1 is taken (another SLURM?): set SLURM_SERVICE_PORT to a free pair"
        fi
    done
    write_conf "$dir"
    export SLURM_CONF=$dir/slurm.conf

    # munged run by root wants its key owned by root: a copy of the package's key (owned by munge)
    install -m 600 -o root -g root /etc/munge/munge.key "$dir/munge.key"
    launch "$dir" munged --socket="$dir/munge.socket" --pid-file="$dir/munged.pid" --log-file="$dir/munged.log" \
        --seed-file="$dir/munged.seed" --key-file="$dir/munge.key"
    # -c: no job or node state of an earlier start in DIR
    launch "$dir" slurmctld -c -f "$SLURM_CONF"
    launch "$dir" slurmd -N "$NODE" -f "$SLURM_CONF"
    wait_for 60 node_idle || die "start: node $NODE not idle after 60 s" \
        "($(sinfo -h -o '%t %E' 2>&1 | head -n1); see $dir/slurmctld.log, $dir/slurmd.log)"
    echo "export SLURM_CONF=$SLURM_CONF"
}

# end DIR NAME...: SIGTERM each daemon NAME this service started (the pid of DIR/NAME.pid, still that
# program), wait up to 10 s for them to exit, SIGKILL any left; nothing else is signalled.
end() {
    local dir=$1 name pid pids=() i
    shift
    for name in "$@"; do
        if ours "$dir" "$name"; then
            pid=$(cat "$dir/$name.pid")
            kill "$pid" && pids+=("$pid")
        fi
    done
    for pid in "${pids[@]}"; do
        for ((i = 0; i < 40; i++)); do
            kill -0 "$pid" 2>/dev/null || break
            sleep 0.25
        done
        if kill -0 "$pid" 2>/dev/null; then kill -9 "$pid"; fi
    done
    for name in "$@"; do rm -f "$dir/$name.pid"; done
}

# munged last: the SLURM daemons use it while they shut down
stop() { end "$1" slurmd slurmctld; end "$1" munged; }

case "${1:-}" in
    install) install_packages ;;
    start) [ $# = 2 ] || die "usage: $0 start DIR"; start "$2" ;;
    stop) [ $# = 2 ] || die "usage: $0 stop DIR"; stop "$2" ;;
    *) die "usage: $0 install | start DIR | stop DIR" ;;
esac
