#!/usr/bin/env bash
# A shared PostgreSQL run store (a throwaway PostgreSQL 15 started here, unix socket only):
# two benches (two data folders) run concurrently through `fringe run --store`; one listing
# shows both, with their provenance; filters by bench and DUT. The database stopped: a run
# still finishes, is kept locally and says forwarding is pending; restarted: the next run
# forwards it. Forwarding is idempotent (the same report again is a no-op) and a different
# report under a stored id is flagged in run_conflicts, never overwritten. Errors name the
# store without its password.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/pg_lib.sh"
dir=$(mktemp -d)
trap 'pg_halt "$dir"; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
pg_start "$dir" || exit 1
# Fig. 10c shortened to 0.25 s (15 000 scored samples, 16 cycles: enough evidence to PASS): the
# test runs it nine times, three at once, also under the sanitizers.
S="$dir/fig10c-short.json"
$PY - "$SRC/fixtures/scenarios/fig10c-loopback.json" "$SRC/fixtures/encoders/paper-d2-analog.json" "$S" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s.update(duration_s=0.25, encoder=sys.argv[2])
json.dump(s, open(sys.argv[3], "w"))
PY

# Two benches at once, three runs each.
bench() {  # NAME SERIAL
  for _ in 1 2 3; do
    "$FRINGE" run "$S" --store "$PGURI" --data "$dir/$1" --bench "$1" --dut "$2" --dut-part P-100 --operator alice -q || return 1
  done
}
bench bench-a SN-A1 & a=$!
bench bench-b SN-B1 & b=$!
wait $a || fail "bench-a runs"
wait $b || fail "bench-b runs"
"$FRINGE" runs --store "$PGURI" --json > "$dir/all.json"
"$FRINGE" runs --store "$PGURI" --json --bench bench-b > "$dir/b.json"
"$FRINGE" runs --store "$PGURI" --json --dut SN-A1 > "$dir/dut.json"
$PY - "$dir" <<'PY' || fail "listing"
import json, sys
d = sys.argv[1]
rows = json.load(open(d + "/all.json"))
assert sorted(r["bench"] for r in rows) == ["bench-a"] * 3 + ["bench-b"] * 3, rows
assert all(r["verdict"] == "PASS" and r["dut_part"] == "P-100" and r["operator"] == "alice" for r in rows), rows
assert [r["created_at"] for r in rows] == sorted((r["created_at"] for r in rows), reverse=True), "newest first"
assert {r["bench"] for r in json.load(open(d + "/b.json"))} == {"bench-b"}
dut = json.load(open(d + "/dut.json"))
assert len(dut) == 3 and {r["dut"] for r in dut} == {"SN-A1"}, dut
PY
# Provenance in the stored report (jsonb) and its columns.
id=$(pg_sql "SELECT id FROM runs WHERE bench = 'bench-a' LIMIT 1")
"$FRINGE" runs --store "$PGURI" --show "$id" --json > "$dir/rep.json"
$PY - "$dir/rep.json" "$id" <<'PY' || fail "provenance"
import json, re, socket, sys
r = json.load(open(sys.argv[1]))
p = r["provenance"]
assert r["id"] == sys.argv[2]
assert re.fullmatch(r"[0-9a-f]{8}-[0-9a-f]{4}-7[0-9a-f]{3}-[89ab][0-9a-f]{3}-[0-9a-f]{12}", r["id"]), r["id"]
assert p["bench"] == "bench-a" and p["host"] == socket.gethostname() and p["operator"] == "alice", p
assert p["dut"] == {"serial": "SN-A1", "part": "P-100"}, p
assert p["fringe_version"] == r["fringe_version"] and re.fullmatch("[0-9a-f]{64}", p["scenario_sha256"]), p
PY
[ "$(pg_sql "SELECT jsonb_typeof(report) FROM runs WHERE id = '$id'")" = object ] || fail "reports are jsonb"
# The scenario as run includes its "dut": one checksum per bench here.
[ "$(pg_sql "SELECT string_agg(n::text, ',') FROM (SELECT COUNT(DISTINCT scenario_sha256) n FROM runs GROUP BY bench) x")" = "1,1" ] || fail "one scenario per bench, one checksum"
[ "$(pg_sql "SELECT COUNT(DISTINCT scenario_sha256) FROM runs")" = 2 ] || fail "two scenarios (two DUTs), two checksums"

# Outage: the run finishes, is kept locally, and forwarding is pending (exit code is the verdict's).
pg_halt "$dir"
"$FRINGE" run "$S" --store "$PGURI" --data "$dir/bench-a" --bench bench-a --forward-wait 1 -q 2> "$dir/down.txt" || fail "a run while the database is down: $(cat "$dir/down.txt")"
grep -q "forwarding pending: 1 run" "$dir/down.txt" || fail "says forwarding is pending: $(cat "$dir/down.txt")"
missed=$("$FRINGE" runs --data "$dir/bench-a" --json | $PY -c 'import json,sys; print(" ".join(r["id"] for r in json.load(sys.stdin) if r["forward"] == "pending"))')
[ -n "$missed" ] || fail "the local history keeps the run as pending"
pg_resume "$dir" || exit 1
[ "$(pg_sql "SELECT COUNT(*) FROM runs WHERE id = '$missed'")" = 0 ] || fail "not forwarded while down"
"$FRINGE" run "$S" --store "$PGURI" --data "$dir/bench-a" --bench bench-a -q 2> "$dir/up.txt" || fail "run after the restart"
grep -q "forwarded 1 earlier run" "$dir/up.txt" || fail "the next run forwards what was missed: $(cat "$dir/up.txt")"
[ "$(pg_sql "SELECT COUNT(*) FROM runs WHERE id = '$missed'")" = 1 ] || fail "the missed run is in the shared store"
[ "$(pg_sql "SELECT COUNT(*) FROM runs WHERE bench = 'bench-a'")" = 5 ] || fail "bench-a has 5 runs"

# Idempotent: the same report forwarded again is a no-op; a different one is flagged, not stored.
db="$dir/bench-a/runs.db"
before=$(pg_sql "SELECT report_sha256 || stored_at FROM runs WHERE id = '$missed'")
$PY -c 'import sqlite3,sys; c=sqlite3.connect(sys.argv[1]); c.execute("UPDATE runs SET forward = ? WHERE id = ?", ("pending", sys.argv[2])); c.commit()' "$db" "$missed"
"$FRINGE" run "$S" --store "$PGURI" --data "$dir/bench-a" --bench bench-a -q 2> "$dir/same.txt" || fail "run (same report again)"
[ "$(pg_sql "SELECT report_sha256 || stored_at FROM runs WHERE id = '$missed'")" = "$before" ] || fail "the same report again changed the row"
[ "$(pg_sql "SELECT COUNT(*) FROM run_conflicts")" = 0 ] || fail "the same report is not a conflict"
$PY - "$db" "$missed" <<'PY'
import json, sqlite3, sys
c = sqlite3.connect(sys.argv[1])
rep = json.loads(c.execute("SELECT report FROM runs WHERE id = ?", (sys.argv[2],)).fetchone()[0])
rep["verdict"] = "FAIL"  # another bench's (or a tampered) report under the same id
c.execute("UPDATE runs SET report = ?, forward = 'pending' WHERE id = ?", (json.dumps(rep), sys.argv[2]))
c.commit()
PY
"$FRINGE" run "$S" --store "$PGURI" --data "$dir/bench-a" --bench bench-a -q 2> "$dir/conflict.txt" || fail "run (conflict)"
grep -q "different report under this id" "$dir/conflict.txt" || fail "the conflict is reported: $(cat "$dir/conflict.txt")"
[ "$(pg_sql "SELECT report->>'verdict' FROM runs WHERE id = '$missed'")" = PASS ] || fail "the stored report was overwritten"
[ "$(pg_sql "SELECT COUNT(*) FROM run_conflicts WHERE id = '$missed' AND report->>'verdict' = 'FAIL'")" = 1 ] || fail "run_conflicts keeps the other report"
"$FRINGE" runs --data "$dir/bench-a" --json | grep -q '"forward": "conflict"' || fail "the local row says conflict"

# Errors name the store without its password, and libpq's reason.
set +e
"$FRINGE" runs --store "postgresql://fringe:s3cret@127.0.0.1:1/runs" 2> "$dir/err.txt"; rc=$?
set -e
[ $rc -eq 2 ] || fail "an unreachable store is exit 2, got $rc"
grep -q "postgresql://fringe:\*\*\*@127.0.0.1:1/runs" "$dir/err.txt" && grep -q "Connection refused" "$dir/err.txt" || fail "error message: $(cat "$dir/err.txt")"
! grep -q s3cret "$dir/err.txt" || fail "the password leaked into a message"
set +e
"$FRINGE" runs --store "mysql://x" 2> "$dir/err2.txt"; rc=$?
set -e
[ $rc -eq 2 ] && grep -q "expected sqlite:PATH or a PostgreSQL URI" "$dir/err2.txt" || fail "unknown store scheme: $(cat "$dir/err2.txt")"
echo "postgres.benches OK"
