#!/bin/sh
# A one-node Slurm cluster on this machine, for tests: tools/slurm/cluster.sh start DIR PORT
# writes DIR/slurm.conf, starts munged, slurmctld and slurmd (state, logs and sockets under
# DIR; slurmctld on PORT, slurmd on PORT+1) and waits until the node is idle; stop DIR kills
# them. Needs root and Debian's slurm-wlm and munge packages. Client commands then need
# SLURM_CONF=DIR/slurm.conf.
set -eu
cmd=$1
dir=$2

stop() {
    for p in slurmd slurmctld; do
        [ -f "$dir/$p.pid" ] && kill "$(cat "$dir/$p.pid")" 2>/dev/null || true
    done
    [ -f "$dir/munge/pid" ] && kill "$(cat "$dir/munge/pid")" 2>/dev/null || true
    return 0
}

case $cmd in
stop)
    stop
    exit 0
    ;;
start) ;;
*)
    echo "usage: $0 start DIR PORT | stop DIR" >&2
    exit 2
    ;;
esac

port=$3
host=$(hostname -s)
mkdir -p "$dir/state" "$dir/spool" "$dir/log" "$dir/munge" "$dir/key"
# munged insists on private key and socket directories owned by its user, on a path that
# everyone may traverse.
chmod 755 "$dir"
chown munge:munge "$dir/munge" "$dir/key"
chmod 755 "$dir/munge"
chmod 700 "$dir/key"
dd if=/dev/urandom of="$dir/key/munge.key" bs=1024 count=1 2>/dev/null
chown munge:munge "$dir/key/munge.key"
chmod 400 "$dir/key/munge.key"
runuser -u munge -- munged --socket="$dir/munge/sock" --key-file="$dir/key/munge.key" \
    --pid-file="$dir/munge/pid" --log-file="$dir/munge/log" --seed-file="$dir/munge/seed"

cat >"$dir/slurm.conf" <<EOF
ClusterName=m6ptest
SlurmctldHost=$host
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$dir/munge/sock
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MpiDefault=none
ReturnToService=2
SchedulerType=sched/builtin
NodeName=$host CPUs=$(nproc) State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$dir/slurm.conf"
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"
i=0
until sinfo -h -o %T 2>/dev/null | grep -qx idle; do
    i=$((i + 1))
    if [ $i -gt 60 ]; then
        echo "the node did not become idle in 30 s; logs in $dir/log" >&2
        stop
        exit 1
    fi
    sleep 0.5
done
