#!/usr/bin/env bash
# The spool (DATA/runs.db) against real PostgreSQL servers (two throwaway ones started here):
# 1. One data folder pointed first at server A, then at a fresh server B: whether a run is
#    stored is B's to say, so the shards' rows and the folder's own runs end up in both.
# 2. A retried shard whose rows all wait in its spool forwards them (exit 0 once delivered)
#    and exits 2 while the store is down, instead of "already stored, running 0" and exit 0.
# 3. A malformed pending row (a report without "scenario") is quarantined with a message
#    naming it: fringe run and fringe serve go on and forward the other rows.
# 4. -0.0 in a report: jsonb gives back 0; the report read back from one store and forwarded
#    again to another is the same report (no conflict).
# 5. A conflict of an earlier run found during a later run's forward wait is reported under
#    the earlier run's id, not the later one's.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
. "$SRC/tests/pg_lib.sh"
dir=$(mktemp -d); pid=
mkdir "$dir/a" "$dir/b"; chmod 711 "$dir"  # the postgres user reaches its two folders
trap 'kill -9 $pid 2>/dev/null || true; pg_halt "$dir/a"; pg_halt "$dir/b"; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
command -v sqlite3 > /dev/null || fail "the sqlite3 command is not installed (Debian package sqlite3; scripts/setup --test installs it)"
pg_start "$dir/a" || exit 1; A=$PGURI
pg_start "$dir/b" || exit 1; B=$PGURI
sqla() { psql "$A" -XAtq -c "$1"; }
sqlb() { psql "$B" -XAtq -c "$1"; }
ids() { psql "$1" -XAtq -c "SELECT string_agg(id, ' ' ORDER BY id) FROM runs WHERE report IS NOT NULL"; }

$PY - "$SRC/fixtures/scenarios/fig10c-loopback.json" "$dir" <<'PY'
import json, sys
b = json.load(open(sys.argv[1]))
b.update(duration_s=0.2, estimators=[{"name": "atan2"}], limits=[])
b["encoder"] = {"model": "ideal", "lines_per_rev": 1024, "vmax_v": 1.0, "noise": {"sigma_add_v": 2e-4}}
cols = [{"estimator": "atan2", "metric": "rms_rad"}]
json.dump({"name": "spool", "base": b, "grid": {"seed": [1, 2, 3, 4, 5, 6]}, "columns": cols}, open(sys.argv[2] + "/sw.json", "w"))
json.dump({"name": "retry", "base": b, "grid": {"seed": [11, 12, 13]}, "columns": cols}, open(sys.argv[2] + "/retry.json", "w"))
json.dump(b, open(sys.argv[2] + "/short.json", "w"))
# -0.0 in the scenario as run (and so in its report).
b["encoder"]["lissajous"] = {"offset_sin_v": -0.0}
json.dump({"name": "signs", "base": b, "grid": {"seed": [21]}, "columns": cols}, open(sys.argv[2] + "/signs.json", "w"))
PY
grep -q -- '-0.0' "$dir/signs.json" || fail "the fixture holds -0.0"

# 1. One folder, server A then a fresh server B.
D="$dir/bench"
"$FRINGE" sweep "$dir/sw.json" --shard 0/2 --store "$A" --data "$D" -q 2> "$dir/s1.txt" || fail "shard 0 into A: $(cat "$dir/s1.txt")"
"$FRINGE" run "$dir/short.json" --store "$A" --data "$D" -q || fail "a run into A"
[ "$(sqla "SELECT COUNT(*) FROM runs")" = 4 ] || fail "A holds shard 0 and the run"
"$FRINGE" sweep "$dir/sw.json" --shard 0/2 --store "$B" --data "$D" 2> "$dir/s2.txt" > /dev/null || fail "shard 0 into B: $(cat "$dir/s2.txt")"
grep -q "3 row(s), 0 already stored, 3 kept in this folder's spool to forward, running 0" "$dir/s2.txt" \
  || fail "B holds none of shard 0: $(cat "$dir/s2.txt")"
[ "$(sqlb "SELECT COUNT(*) FROM runs WHERE id LIKE 'sweep-%'")" = 3 ] || fail "shard 0 is in B: $(sqlb "SELECT COUNT(*) FROM runs")"
"$FRINGE" sweep "$dir/sw.json" --shard 1/2 --store "$B" --data "$D" -q || fail "shard 1 into B"
"$FRINGE" sweep "$dir/sw.json" --shard 1/2 --store "$A" --data "$D" 2> "$dir/s3.txt" > /dev/null || fail "shard 1 into A"
grep -q "running 0" "$dir/s3.txt" || fail "shard 1 is not run again for A: $(cat "$dir/s3.txt")"
"$FRINGE" run "$dir/short.json" --store "$B" --data "$D" -q || fail "a run into B"
"$FRINGE" run "$dir/short.json" --store "$A" --data "$D" -q || fail "a second run into A"
# Retried shards, to A then to B: each forwards the runs its store has not seen.
"$FRINGE" sweep "$dir/sw.json" --shard 0/2 --store "$A" --data "$D" -q || fail "shard 0 into A again"
"$FRINGE" sweep "$dir/sw.json" --shard 1/2 --store "$B" --data "$D" -q || fail "shard 1 into B again"
spool=$(sqlite3 "$D/runs.db" "SELECT group_concat(id, ' ') FROM (SELECT id FROM runs WHERE report IS NOT NULL ORDER BY id)")
[ "$(ids "$A")" = "$spool" ] || fail "A holds every run of the folder: A=$(ids "$A") spool=$spool"
[ "$(ids "$B")" = "$spool" ] || fail "B holds every run of the folder: B=$(ids "$B") spool=$spool"
[ "$(echo "$spool" | wc -w)" = 9 ] || fail "6 sweep rows and 3 runs: $spool"
[ "$(sqla "SELECT COUNT(*) FROM run_conflicts")$(sqlb "SELECT COUNT(*) FROM run_conflicts")" = 00 ] || fail "no conflicts"
"$FRINGE" sweep "$dir/sw.json" --collect --store "$A" -q || fail "--collect from A"
"$FRINGE" sweep "$dir/sw.json" --collect --store "$B" -q || fail "--collect from B"
# The spool names the store each row reached (its system identifier and database).
sysb=$(sqlb "SELECT system_identifier FROM pg_control_system()")
[ "$(sqlite3 "$D/runs.db" "SELECT COUNT(*) FROM runs WHERE forward = 'done' AND forward_store = 'pg:$sysb/postgres'")" = 9 ] \
  || fail "rows name the store they reached: $(sqlite3 "$D/runs.db" "SELECT forward, forward_store FROM runs")"
echo "1. one folder, two servers: every row in both"

# 2. A retried shard whose rows wait in the spool.
R="$dir/retry"
pg_halt "$dir/b"
set +e; "$FRINGE" sweep "$dir/retry.json" --shard 0/1 --store "$B" --data "$R" --forward-wait 1 -q 2> "$dir/r1.txt"; rc=$?; set -e
[ $rc = 2 ] || fail "a shard that could not forward exits 2, got $rc: $(cat "$dir/r1.txt")"
set +e; "$FRINGE" sweep "$dir/retry.json" --shard 0/1 --store "$B" --data "$R" --forward-wait 1 2> "$dir/r2.txt" > /dev/null; rc=$?; set -e
[ $rc = 2 ] || fail "its retry while the store is still down exits 2, got $rc: $(cat "$dir/r2.txt")"
grep -q "forwarding pending" "$dir/r2.txt" || fail "the retry says the rows are pending: $(cat "$dir/r2.txt")"
pg_resume "$dir/b" || exit 1
"$FRINGE" sweep "$dir/retry.json" --shard 0/1 --store "$B" --data "$R" 2> "$dir/r3.txt" > /dev/null || fail "the retry with the store back: $(cat "$dir/r3.txt")"
grep -q "3 kept in this folder's spool to forward, running 0" "$dir/r3.txt" || fail "the retry forwards the kept rows: $(cat "$dir/r3.txt")"
[ "$(sqlb "SELECT COUNT(*) FROM runs WHERE scenario = 'fig10c-loopback' AND id LIKE 'sweep-%'")" = 9 ] || fail "the retried shard's rows are in B"
"$FRINGE" sweep "$dir/retry.json" --collect --store "$B" -q || fail "--collect finds the retried shard"
echo "2. a retried shard forwards its kept rows"

# 3. A malformed pending row.
sqlite3 "$D/runs.db" "INSERT INTO runs (id, created_at, scenario, dut, status, verdict, report, forward)
  SELECT 'malformed-0001', created_at, scenario, dut, status, verdict, json_remove(json_set(report, '$.id', 'malformed-0001'), '$.scenario'), 'pending'
  FROM runs WHERE id LIKE 'sweep-%' LIMIT 1"
"$FRINGE" run "$dir/short.json" --store "$B" --data "$D" --report "$dir/after.json" -q 2> "$dir/m1.txt" \
  || fail "fringe run with a malformed row in the spool: $(cat "$dir/m1.txt")"
grep -q 'run malformed-0001: its spooled report cannot be forwarded (the report has no "scenario" object)' "$dir/m1.txt" \
  || fail "the malformed row is named with its problem: $(cat "$dir/m1.txt")"
[ "$(sqlite3 "$D/runs.db" "SELECT forward FROM runs WHERE id = 'malformed-0001'")" = quarantined ] || fail "the malformed row is quarantined"
new=$($PY -c 'import json,sys; print(json.load(open(sys.argv[1]))["id"])' "$dir/after.json")
[ "$(sqlb "SELECT COUNT(*) FROM runs WHERE id = '$new'")" = 1 ] || fail "the run beside a malformed row is forwarded"
[ "$(sqlb "SELECT COUNT(*) FROM runs WHERE id = 'malformed-0001'")" = 0 ] || fail "the malformed row is not sent"
# fringe serve on that spool with one more malformed row pending: it stays up and forwards.
sqlite3 "$D/runs.db" "UPDATE runs SET id = 'malformed-0002', report = json_set(report, '$.id', 'malformed-0002'), forward = 'pending' WHERE id = 'malformed-0001'"
"$FRINGE" serve --bind 127.0.0.1:0 --data "$D" --store "$B" > "$dir/serve.out" 2> "$dir/serve.log" & pid=$!
URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 100 0.1) || fail "fringe serve did not start: $(cat "$dir/serve.log")"
for _ in $(seq 100); do grep -q "malformed-0002" "$dir/serve.log" && break; sleep 0.1; done
grep -q "run malformed-0002: its spooled report cannot be forwarded" "$dir/serve.log" || fail "serve names the malformed row: $(cat "$dir/serve.log")"
sleep 0.5
kill -0 $pid 2>/dev/null || fail "serve died on a malformed spool row: $(cat "$dir/serve.log")"
[ "$(curl -sS --max-time 5 -o /dev/null -w '%{http_code}' "${URL}api/v1/health")" = 200 ] || fail "serve answers health"
kill -TERM $pid; wait $pid || fail "serve exits 0 on SIGTERM"; pid=
echo "3. a malformed spool row is quarantined"

# 4. -0.0 through jsonb: a sweep row (one id on every host) in A and in B from two folders;
#    the report read back from B, forwarded again to A from a third folder, is the same report.
"$FRINGE" sweep "$dir/signs.json" --shard 0/1 --store "$A" --data "$dir/signs-a" -q || fail "the row with -0.0 into A"
"$FRINGE" sweep "$dir/signs.json" --shard 0/1 --store "$B" --data "$dir/signs-b" -q || fail "the row with -0.0 into B"
sid=$(sqlite3 "$dir/signs-a/runs.db" "SELECT id FROM runs")
sqlite3 "$dir/signs-a/runs.db" "SELECT report FROM runs" | tr -d ' ' | grep -q '"offset_sin_v":-0.0' || fail "the report holds -0.0"
[ "$(sqlb "SELECT report->'scenario'->'encoder'->'lissajous'->>'offset_sin_v' FROM runs WHERE id = '$sid'")" = 0.0 ] || fail "jsonb stores -0.0 as 0"
E="$dir/restored"
"$FRINGE" runs --data "$E" > /dev/null  # creates the folder's runs.db
sqlb "SELECT report::text FROM runs WHERE id = '$sid'" > "$dir/back.json"
sqlite3 "$E/runs.db" "INSERT INTO runs (id, created_at, scenario, dut, status, verdict, report, forward)
  VALUES ('$sid', '2026-01-01T00:00:00Z', 'signs', '', 'done', 'PASS', readfile('$dir/back.json'), 'pending')"
"$FRINGE" run "$dir/short.json" --store "$A" --data "$E" -q 2> "$dir/j.txt" || fail "forwarding the read-back report: $(cat "$dir/j.txt")"
[ "$(sqlite3 "$E/runs.db" "SELECT forward FROM runs WHERE id = '$sid'")" = done ] || fail "the read-back report is the same one: $(cat "$dir/j.txt")"
[ "$(sqla "SELECT COUNT(*) FROM run_conflicts WHERE id = '$sid'")" = 0 ] || fail "a report read back through jsonb is not a conflict"
echo "4. checksums survive jsonb"

# 5. An earlier run's conflict found during a later run's forward wait.
old=$(sqlite3 "$D/runs.db" "SELECT id FROM runs WHERE id LIKE 'sweep-%' ORDER BY id DESC LIMIT 1")
sqlite3 "$D/runs.db" "UPDATE runs SET report = json_set(report, '$.verdict', 'FAIL'), report_sha256 = 'changed', forward = 'pending' WHERE id = '$old'"
pg_halt "$dir/b"
$PY -c 'import json,sys; b=json.load(open(sys.argv[1])); b["duration_s"]=3; json.dump(b, open(sys.argv[2], "w"))' "$dir/short.json" "$dir/slow.json"
"$FRINGE" run "$dir/slow.json" --store "$B" --data "$D" --report "$dir/late.json" --forward-wait 60 -q > /dev/null 2> "$dir/c.txt" & pid=$!
sleep 0.3
pg_resume "$dir/b" || exit 1
wait $pid || true; pid=
late=$($PY -c 'import json,sys; print(json.load(open(sys.argv[1]))["id"])' "$dir/late.json")
grep -q "run $old.*different report" "$dir/c.txt" || fail "the conflict is reported under its own id $old: $(cat "$dir/c.txt")"
if grep "different report" "$dir/c.txt" | grep -q "$late"; then fail "the conflict is reported under the later run's id $late: $(cat "$dir/c.txt")"; fi
[ "$(sqlb "SELECT COUNT(*) FROM runs WHERE id = '$late'")" = 1 ] || fail "the later run is forwarded"
echo "5. a conflict under its own id"
echo "postgres.spool OK"
