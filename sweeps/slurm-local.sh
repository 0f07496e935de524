#!/usr/bin/env bash
# A one-node Slurm cluster on this machine, for trying `hydra/launcher=slurm` and for CI's
# `cluster` tests: munged, slurmctld and slurmd as root, listening on 127.0.0.1 only, their
# config, state and logs in one temporary folder.
#
#   eval "$(sweeps/slurm-local.sh start)"   # installs slurm-wlm and munge if missing (apt-get),
#                                           # waits for the node to be idle, prints the export
#   sweeps/slurm-local.sh status            # up or down; prints the same export when up
#   sweeps/slurm-local.sh stop              # cancels its jobs, ends the daemons it started
#
# `start` is idempotent (a cluster already up is left as it is). `stop` ends only the daemons
# whose pids it recorded at start, then removes what it wrote. Client commands (sinfo, sbatch and
# submitit through them) find the cluster through SLURM_CONF, the line `start` prints.
# EDR_SLURM_DIR moves the folder (default: $TMPDIR/edr-slurm); EDR_SLURM_PORT picks the
# controller's port (the node's is the next one).
set -euo pipefail

DIR="${EDR_SLURM_DIR:-${TMPDIR:-/tmp}/edr-slurm}"
PORT="${EDR_SLURM_PORT:-6817}"
CONF="$DIR/slurm.conf"
DAEMONS=(munged slurmctld slurmd)  # started in this order, stopped in the reverse one

say() { echo "slurm-local: $*" >&2; }

pid_of() {  # the pid this script recorded for daemon $1, if that daemon still runs under it
    local file="$DIR/pids/$1.pid" pid
    [[ -s "$file" ]] || return 1
    pid="$(<"$file")"
    [[ "$(ps -o comm= -p "$pid" 2>/dev/null)" == "$1" ]] && echo "$pid"
}

node_state() { SLURM_CONF="$CONF" sinfo -h -N -o "%t" 2>/dev/null | head -n1 || true; }

install_packages() {
    local missing=()
    command -v slurmctld >/dev/null && command -v slurmd >/dev/null && command -v sinfo >/dev/null \
        || missing+=(slurm-wlm)
    command -v munged >/dev/null || missing+=(munge)
    [[ ${#missing[@]} -eq 0 ]] && return
    command -v apt-get >/dev/null || { say "missing ${missing[*]} and no apt-get: install them"; exit 1; }
    say "installing ${missing[*]} (apt-get)"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >&2 && apt-get install -y -qq --no-install-recommends "${missing[@]}" >&2
}

write_config() {
    local host node
    host="$(hostname -s)"
    # This machine's CPUs, sockets, cores and memory, as slurmd measures them.
    node="$(slurmd -C | head -n1)"
    mkdir -p "$DIR"/{munge,state,spool,log,pids}
    chown munge:munge "$DIR/munge" && chmod 0755 "$DIR/munge"  # clients reach its socket
    [[ -s "$DIR/munge/munge.key" ]] || {
        dd if=/dev/urandom of="$DIR/munge/munge.key" bs=1024 count=1 status=none
        chown munge:munge "$DIR/munge/munge.key" && chmod 0400 "$DIR/munge/munge.key"
    }
    cat >"$CONF" <<EOF
# Written by sweeps/slurm-local.sh: a one-node cluster on 127.0.0.1.
ClusterName=edr-local
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
CommunicationParameters=NoCtldInAddrAny,NoInAddrAny
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$DIR/munge/munge.socket
CredType=cred/munge
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/state/slurmctld.pid
SlurmdPidFile=$DIR/spool/slurmd.pid
SlurmctldLogFile=$DIR/log/slurmctld.log
SlurmdLogFile=$DIR/log/slurmd.log
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
ReturnToService=2
SlurmdTimeout=60
MinJobAge=60
KillWait=5
NodeName=${node#NodeName=} NodeAddr=127.0.0.1 State=UNKNOWN
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
    # slurmd -C names the node as the machine does; the partition above uses the same name.
    grep -q "^NodeName=$host " "$CONF" || { say "slurmd -C does not name this host ($host)"; exit 1; }
}

start_daemon() {  # name, the pid file and log it writes, its command; records its pid
    local name="$1" pidfile="$2" logfile="$3" pid
    shift 3
    pid_of "$name" >/dev/null && return
    rm -f "$pidfile"
    "$@"
    for _ in $(seq 100); do
        pid="$(cat "$pidfile" 2>/dev/null || true)"
        if [[ -n "$pid" ]] && kill -0 "$pid" 2>/dev/null; then
            echo "$pid" >"$DIR/pids/$name.pid"
            return
        fi
        sleep 0.1
    done
    say "$name did not start (sweeps/slurm-local.sh stop ends the others); its log: $logfile"
    tail -n 20 "$logfile" >&2 2>/dev/null || true
    exit 1
}

start() {
    if [[ -n "$(pid_of slurmd || true)" && "$(node_state)" =~ ^(idle|mix|alloc) ]]; then
        say "up already (node $(node_state))"
        echo "export SLURM_CONF=$CONF"
        return
    fi
    install_packages
    write_config
    local m="$DIR/munge"  # munged runs as the munge user: its files live in its own folder
    start_daemon munged "$m/munged.pid" "$m/munged.log" runuser -u munge -- munged \
        --key-file="$m/munge.key" --socket="$m/munge.socket" --pid-file="$m/munged.pid" \
        --log-file="$m/munged.log" --seed-file="$m/munged.seed"
    start_daemon slurmctld "$DIR/state/slurmctld.pid" "$DIR/log/slurmctld.log" slurmctld -f "$CONF"
    start_daemon slurmd "$DIR/spool/slurmd.pid" "$DIR/log/slurmd.log" slurmd -f "$CONF"
    local state=""
    for _ in $(seq 120); do
        state="$(node_state)"
        [[ "$state" == idle ]] && break
        sleep 0.5
    done
    if [[ "$state" != idle ]]; then
        say "the node is '${state:-unreachable}', not idle, after 60 s; logs in $DIR/log" \
            "(sweeps/slurm-local.sh stop ends the daemons)"
        tail -n 20 "$DIR/log/slurmctld.log" "$DIR/log/slurmd.log" >&2 2>/dev/null || true
        exit 1
    fi
    say "up: node $(hostname -s) idle on 127.0.0.1:$PORT, config $CONF"
    echo "export SLURM_CONF=$CONF"
}

stop() {
    if [[ -n "$(pid_of slurmctld || true)" ]]; then  # jobs left behind would outlive slurmd
        SLURM_CONF="$CONF" scancel --full --signal=KILL --partition=local 2>/dev/null || true
        sleep 1
    fi
    local name pid stopped=()
    for ((i = ${#DAEMONS[@]} - 1; i >= 0; i--)); do
        name="${DAEMONS[i]}"
        pid="$(pid_of "$name" || true)"
        [[ -n "$pid" ]] || continue
        kill "$pid"
        for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        kill -0 "$pid" 2>/dev/null && kill -KILL "$pid"
        stopped+=("$name ($pid)")
    done
    # Only what start wrote: EDR_SLURM_DIR may name a folder that holds other files too.
    rm -rf "${DIR:?}"/{munge,state,spool,log,pids} "$CONF"
    rmdir "$DIR" 2>/dev/null || true
    say "stopped: ${stopped[*]:-nothing was running}"
}

status() {
    local name pid state
    for name in "${DAEMONS[@]}"; do
        pid="$(pid_of "$name" || true)"
        say "$name: ${pid:-not running}"
    done
    state=""  # sinfo without a controller waits on DNS lookups for minutes: ask only a live one
    if [[ -n "$(pid_of slurmctld || true)" && -f "$CONF" ]]; then state="$(node_state)"; fi
    if [[ -z "$state" ]]; then
        say "down (start it: eval \"\$(sweeps/slurm-local.sh start)\")"
        return 1
    fi
    say "up: node $(hostname -s) $state, config $CONF"
    echo "export SLURM_CONF=$CONF"
}

case "${1:-}" in
    start | stop | status) "$1" ;;
    *) echo "usage: $0 start|stop|status" >&2; exit 2 ;;
esac
