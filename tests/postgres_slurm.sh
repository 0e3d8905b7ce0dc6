#!/usr/bin/env bash
# The sweep shards as a real Slurm job array: a single-node Slurm (Debian's slurm-wlm:
# slurmctld + slurmd with their own munged, config, state and ports in a temp folder) and a
# throwaway PostgreSQL 15, both started here and stopped after. `sbatch --array=0-2` runs
# `fringe sweep --store` with the shard taken from SLURM_ARRAY_TASK_ID/COUNT; --collect from
# the store equals the single-process sweep. Table 1 at duration_s 0.2 (the job array, not the
# rows, is what this tests). slurmd runs jobs as their user and needs root: run as root.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/pg_lib.sh"
dir=$(mktemp -d)
cleanup() {
  [ -n "${SLURM_CONF:-}" ] && scancel --quiet -u root 2>/dev/null || true
  for p in slurmd slurmctld munged; do [ -f "$dir/$p.pid" ] && kill "$(cat "$dir/$p.pid")" 2>/dev/null || true; done
  sleep 0.5
  for p in slurmd slurmctld munged; do [ -f "$dir/$p.pid" ] && kill -9 "$(cat "$dir/$p.pid")" 2>/dev/null || true; done
  pg_halt "$dir"
  rm -rf "$dir"
}
trap cleanup EXIT
fail() { echo "FAIL: $*" >&2; for f in "$dir"/ctld.log "$dir"/d.log "$dir"/out-*.txt; do [ -f "$f" ] && { echo "== $f" >&2; tail -20 "$f" >&2; }; done; exit 1; }
[ "$(id -u)" = 0 ] || fail "slurmd runs jobs as their user and must run as root; run this test as root"
for b in munged slurmctld slurmd sbatch; do command -v $b > /dev/null || fail "$b not found (Debian package slurm-wlm; scripts/setup --test installs it)"; done
[ -r /etc/munge/munge.key ] || fail "no /etc/munge/munge.key (Debian's munge package creates it)"
pg_start "$dir" || exit 1

# munged on its own socket, as the munge user.
install -d -o munge -g munge -m 0700 "$dir/munge"
runuser -u munge -- munged --force --socket="$dir/munge/sock" --key-file=/etc/munge/munge.key --pid-file="$dir/munge/pid" \
  --log-file="$dir/munge/log" --seed-file="$dir/munge/seed" || fail "munged did not start"
cp "$dir/munge/pid" "$dir/munged.pid"
read -r p1 p2 < <($PY -c 'import socket
s=[socket.socket() for _ in range(2)]
[x.bind(("127.0.0.1",0)) for x in s]
print(*[x.getsockname()[1] for x in s])')
host=$(hostname -s)
mkdir -p "$dir/state" "$dir/spool"
cat > "$dir/slurm.conf" <<CONF
ClusterName=fringe-test
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$dir/munge/sock
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/ctld.log
SlurmdLogFile=$dir/d.log
SlurmctldPort=$p1
SlurmdPort=$p2
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
MpiDefault=none
NodeName=$host CPUs=$(nproc) State=UNKNOWN
PartitionName=test Nodes=$host Default=YES MaxTime=30 State=UP
CONF
export SLURM_CONF="$dir/slurm.conf"
slurmctld -c -f "$SLURM_CONF" || fail "slurmctld did not start"
slurmd -f "$SLURM_CONF" || fail "slurmd did not start"
for _ in $(seq 100); do sinfo -h -o %t 2>/dev/null | grep -q idle && break; sleep 0.2; done
sinfo -h -o %t | grep -q idle || fail "the node did not become idle: $(sinfo 2>&1)"

T="$dir/table1.json"
$PY - "$SRC/fixtures/sweeps/table1.json" "$T" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["base"]["duration_s"] = 0.2
json.dump(s, open(sys.argv[2], "w"))
PY
"$FRINGE" sweep "$T" --csv "$dir/single.csv" --md "$dir/single.md" -q || fail "single-process sweep"
cat > "$dir/shard.sh" <<JOB
#!/bin/bash
exec "$FRINGE" sweep "$T" --store "$PGURI" --data "$dir/node-\$SLURM_ARRAY_TASK_ID" --jobs 1
JOB
chmod +x "$dir/shard.sh"
timeout 300 sbatch --array=0-2 --cpus-per-task=1 --output="$dir/out-%a.txt" --wait "$dir/shard.sh" > /dev/null || fail "the job array failed"
for i in 0 1 2; do grep -q "shard $i/3: " "$dir/out-$i.txt" || fail "array task $i ran shard $i/3: $(cat "$dir/out-$i.txt")"; done
"$FRINGE" sweep "$T" --collect --store "$PGURI" --csv "$dir/c.csv" --md "$dir/c.md" -q || fail "--collect after the job array"
cmp "$dir/single.md" "$dir/c.md" || fail "the collected table differs: $(diff "$dir/single.md" "$dir/c.md")"
echo "postgres.slurm OK"
