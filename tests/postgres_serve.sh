#!/usr/bin/env bash
# `fringe serve --store postgresql://...` (a throwaway PostgreSQL 15 started here): the API
# lists every bench's runs (another bench's, forwarded by `fringe run --store`, and its own),
# filtered by bench and DUT (GET /api/v1/runs?bench=...&dut=...), and serves another bench's
# report from the shared store. The database stopped while the service runs: runs still
# finish and are listed (from DATA/runs.db); restarted, the forwarder delivers what it missed
# without a restart of the service.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
. "$SRC/tests/pg_lib.sh"
dir=$(mktemp -d); pid=
trap 'kill -9 $pid 2>/dev/null || true; pg_halt "$dir"; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; [ -f "$dir/serve.log" ] && cat "$dir/serve.log" >&2; exit 1; }
pg_start "$dir" || exit 1
S="$SRC/fixtures/scenarios/fig10c-loopback.json"

"$FRINGE" run "$S" --store "$PGURI" --data "$dir/bench-a" --bench bench-a --dut SN-A1 -q || fail "bench-a run"
aid=$(pg_sql "SELECT id FROM runs WHERE bench = 'bench-a'")

"$FRINGE" serve --bind 127.0.0.1:0 --data "$dir/bench-c" --store "$PGURI" --bench bench-c --dut SN-C1 --dut-part P-200 \
  > "$dir/serve.out" 2> "$dir/serve.log" &
pid=$!
URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 100 0.1) || fail "fringe serve did not start"
grep -q "run store postgresql:///postgres?host=.*bench bench-c" "$dir/serve.out" || fail "serve names its store: $(cat "$dir/serve.out")"
T="$dir/bench-c/token"
api() { curl -sS --max-time 10 "$@"; }
count() { api "${URL}api/v1/runs$1" | $PY -c 'import json,sys; rs=json.load(sys.stdin)["runs"]; print(len(rs), " ".join(sorted({r["bench"] + ":" + r["dut"] for r in rs})))'; }
wait_pg() {  # wait_pg SQL EXPECTED: up to 60 s (the forwarder's backoff reaches 16 s)
  for _ in $(seq 240); do [ "$(pg_sql "$1" 2>/dev/null)" = "$2" ] && return 0; sleep 0.25; done
  return 1
}

"$FRINGE" run "$S" --server "$URL" --token-file "$T" -q || fail "a run on the service"
wait_pg "SELECT COUNT(*) FROM runs WHERE bench = 'bench-c'" 1 || fail "the service forwards its run"
[ "$(count "")" = "2 bench-a:SN-A1 bench-c:SN-C1" ] || fail "every bench's runs: $(count "")"
[ "$(count "?bench=bench-a")" = "1 bench-a:SN-A1" ] || fail "?bench=bench-a: $(count "?bench=bench-a")"
[ "$(count "?dut=SN-C1")" = "1 bench-c:SN-C1" ] || fail "?dut=SN-C1: $(count "?dut=SN-C1")"
[ "$(count "?bench=bench-c&dut=SN-A1")" = "0 " ] || fail "both filters: $(count "?bench=bench-c&dut=SN-A1")"
[ "$(pg_sql "SELECT dut_part FROM runs WHERE bench = 'bench-c'")" = P-200 ] || fail "the service's --dut-part"
# Another bench's report, from the shared store.
api "${URL}api/v1/runs/$aid/report.json" | $PY -c 'import json,sys; r=json.load(sys.stdin); assert r["provenance"]["bench"] == "bench-a", r' \
  || fail "another bench's report through this service"
code=$(api -o /dev/null -w '%{http_code}' "${URL}api/v1/runs?benchx=1")
[ "$code" = 400 ] || fail "an unknown filter is 400, got $code"

# Outage while the service runs.
pg_halt "$dir"
for _ in 1 2; do "$FRINGE" run "$S" --server "$URL" --token-file "$T" -q || fail "a run while the database is down"; done
[ "$(count "?bench=bench-c")" = "3 bench-c:SN-C1" ] || fail "the service lists its runs while the database is down: $(count "?bench=bench-c")"
pg_resume "$dir" || exit 1
wait_pg "SELECT COUNT(*) FROM runs WHERE bench = 'bench-c'" 3 || fail "the runs missed during the outage were forwarded after the restart"
[ "$(pg_sql "SELECT COUNT(*) FROM runs WHERE bench = 'bench-c' AND report->>'verdict' = 'PASS'")" = 3 ] || fail "forwarded reports"
kill -TERM $pid; wait $pid || fail "serve exits 0 on SIGTERM"; pid=
echo "postgres.serve OK"
