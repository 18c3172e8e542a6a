#!/usr/bin/env bash
# The robustness sweep as a Slurm job array, on a single-node Slurm this
# script brings up on this machine: Debian's slurm-wlm and munge (installed
# with apt when missing, as root), slurmctld and slurmd on 127.0.0.1, one
# partition of this machine's cores. It submits the book's array job
# (`tools/sweep.sbatch`, one shard per task), waits for it, merges the
# shards with `sil-host sweep merge`, flies the same sweep on one machine
# and checks that the two `sweep.json` files are equal byte for byte.
#
#   tools/slurm_sweep.sh SIL_HOST [--tasks 8] [--samples 16] [--duration 4] [--out DIR]
#
# Prints the job id, every task's state, the shard files and a closing
# `slurm check: N passed, N failed` line. The daemons it started are
# stopped on exit; a Slurm that was already running is left alone and used.
set -euo pipefail

usage() { echo "usage: $0 SIL_HOST [--tasks N] [--samples N] [--duration S] [--out DIR]" >&2; exit 2; }
[ $# -ge 1 ] || usage
SIL=$(realpath "$1"); shift
TASKS=8 SAMPLES=16 DURATION=4 OUT=target/slurm-sweep
while [ $# -gt 0 ]; do
    case "$1" in
        --tasks) TASKS=$2; shift 2 ;;
        --samples) SAMPLES=$2; shift 2 ;;
        --duration) DURATION=$2; shift 2 ;;
        --out) OUT=$2; shift 2 ;;
        *) usage ;;
    esac
done
[ -x "$SIL" ] || { echo "slurm_sweep: $SIL is not an executable sil-host" >&2; exit 2; }
HERE=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$OUT"
OUT=$(realpath "$OUT")
rm -rf "$OUT"/shards "$OUT"/merged "$OUT"/single "$OUT"/logs
mkdir -p "$OUT"/shards "$OUT"/logs

if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    echo "== installing slurm-wlm and munge (apt)"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends slurm-wlm munge >/dev/null
fi

started=()
cleanup() {
    for p in "${started[@]}"; do $SUDO pkill -x "$p" 2>/dev/null || true; done
}
trap cleanup EXIT

# munge: the key Debian's package made, the daemon as its own user.
if ! pgrep -x munged >/dev/null; then
    [ -s /etc/munge/munge.key ] || $SUDO mungekey --create --force
    $SUDO mkdir -p /run/munge /var/log/munge /var/lib/munge
    $SUDO chown munge:munge /run/munge /var/log/munge /var/lib/munge /etc/munge /etc/munge/munge.key
    $SUDO chmod 0700 /etc/munge /var/log/munge /var/lib/munge
    $SUDO chmod 0400 /etc/munge/munge.key
    $SUDO runuser -u munge -- /usr/sbin/munged
    started+=(munged)
fi

# One node, this machine, addressed on loopback; no cgroups, no accounting.
if ! pgrep -x slurmctld >/dev/null; then
    NODE=$(hostname -s)
    CPUS=$(nproc)
    MEM=$(awk '/MemTotal/ { printf "%d", $2 / 1024 * 0.8 }' /proc/meminfo)
    conf=$(mktemp)
    cat > "$conf" <<EOF
ClusterName=fcsweep
SlurmctldHost=${NODE}(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MpiDefault=none
ReturnToService=2
StateSaveLocation=/var/lib/slurm/slurmctld
SlurmdSpoolDir=/var/lib/slurm/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
NodeName=${NODE} NodeAddr=127.0.0.1 CPUs=${CPUS} RealMemory=${MEM} State=UNKNOWN
PartitionName=sweep Nodes=${NODE} Default=YES MaxTime=INFINITE State=UP
EOF
    $SUDO mkdir -p /etc/slurm /var/lib/slurm/slurmctld /var/lib/slurm/slurmd /var/log/slurm
    $SUDO cp "$conf" /etc/slurm/slurm.conf
    rm -f "$conf"
    $SUDO slurmctld -c   # a clean controller state: no jobs left from an earlier run
    started+=(slurmctld)
    $SUDO slurmd
    started+=(slurmd)
fi

# Wait (bounded) for the node to be ready.
for _ in $(seq 1 60); do
    state=$(sinfo -h -o '%T' 2>/dev/null | head -n 1 || true)
    case "$state" in idle|mixed|allocated) break ;; esac
    sleep 1
done
echo "node: $(sinfo -h -o '%N %T %c CPUs' | head -n 1)"

# The array job, as the book gives it (one shard per task).
export SIL_HOST="$SIL" SWEEP_SAMPLES="$SAMPLES" SWEEP_DURATION="$DURATION" SWEEP_SHARDS="$TASKS" SWEEP_OUT="$OUT/shards"
job=$(sbatch --parsable --array=0-$((TASKS - 1)) --output="$OUT/logs/task-%a.out" --export=ALL "$HERE/sweep.sbatch")
job=${job%%;*}
echo "submitted job array $job ($TASKS tasks)"
# Wait until the array has left the queue (bounded: 20 minutes).
for _ in $(seq 1 1200); do
    [ -z "$(squeue -h -j "$job" 2>/dev/null)" ] && break
    sleep 1
done
pass=0 fail=0
check() { if "$@"; then pass=$((pass + 1)); else fail=$((fail + 1)); fi; }
# Each task's final state from the controller (no accounting database:
# scontrol remembers finished jobs for MinJobAge, 300 s by default).
completed=0
for i in $(seq 0 $((TASKS - 1))); do
    st=$(scontrol show job "${job}_${i}" 2>/dev/null | sed -n 's/.*JobState=\([A-Z_]*\).*/\1/p' | head -n 1)
    id=$(scontrol show job "${job}_${i}" 2>/dev/null | sed -n 's/^JobId=\([0-9]*\) .*/\1/p' | head -n 1)
    echo "task $i: job id ${id:-?} (${job}_${i}) ${st:-unknown}"
    [ "$st" = COMPLETED ] && completed=$((completed + 1))
done
check [ "$completed" -eq "$TASKS" ]
echo "shards:"
ls -l "$OUT"/shards
check [ "$(find "$OUT"/shards -name 'shard-*-of-'"$TASKS"'.jsonl' | wc -l)" -eq "$TASKS" ]

"$SIL" sweep merge "$OUT"/shards --out "$OUT"/merged >/dev/null
"$SIL" sweep --samples "$SAMPLES" --duration "$DURATION" --no-progress --out "$OUT"/single >/dev/null
if cmp "$OUT"/merged/sweep.json "$OUT"/single/sweep.json; then
    echo "merged sweep.json equals the one-machine sweep.json byte for byte ($(wc -c < "$OUT"/single/sweep.json) B)"
    pass=$((pass + 1))
else
    echo "merged sweep.json differs from the one-machine sweep.json"
    fail=$((fail + 1))
fi
echo "slurm check: $pass passed, $fail failed"
[ "$fail" -eq 0 ]
