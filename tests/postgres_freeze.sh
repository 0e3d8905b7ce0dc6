#!/usr/bin/env bash
# A shared PostgreSQL that stops answering (every server process SIGSTOPped: connections stay
# open, nothing replies) while `fringe serve --store postgresql://...` runs. The statement
# deadline (FRINGE_STORE_TIMEOUT_S=2 here) turns it into "store unreachable": GET /runs answers
# within the deadline with this bench's runs and "partial": true; another bench's run is 503
# store_unreachable (not 404); /health answers at once throughout and reports the store
# unreachable with the forwarding backlog; runs posted meanwhile finish into the spool. Resumed
# (SIGCONT), the backlog is forwarded and health says reachable, pending 0. A reader
# (`fringe runs --store`) on the frozen database fails within the deadline, exit 2.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
. "$SRC/tests/pg_lib.sh"
dir=$(mktemp -d); pid=; frozen=
thaw() { [ -n "$frozen" ] && kill -CONT $frozen 2>/dev/null; frozen=; return 0; }
trap 'thaw; kill -9 $pid 2>/dev/null || true; pg_halt "$dir"; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; [ -f "$dir/serve.log" ] && tail -20 "$dir/serve.log" >&2; exit 1; }
pg_start "$dir" || exit 1
export FRINGE_STORE_TIMEOUT_S=2
S="$dir/short.json"
$PY - "$SRC/fixtures/scenarios/fig10c-loopback.json" "$SRC/fixtures/encoders/paper-d2-analog.json" "$S" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s.update(duration_s=0.25, encoder=sys.argv[2])
json.dump(s, open(sys.argv[3], "w"))
PY

"$FRINGE" run "$S" --store "$PGURI" --data "$dir/bench-a" --bench bench-a -q || fail "bench-a run"
aid=$(pg_sql "SELECT id FROM runs WHERE bench = 'bench-a'")
"$FRINGE" serve --bind 127.0.0.1:0 --data "$dir/bench-c" --store "$PGURI" --bench bench-c > "$dir/serve.out" 2> "$dir/serve.log" &
pid=$!
URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 100 0.1) || fail "fringe serve did not start"
T="$dir/bench-c/token"
api() { curl -sS --max-time 30 "$@"; }
api "${URL}api/v1/runs/$aid" | grep -q '"bench-a"\|"id"' || fail "another bench's run while the database answers"
health() { api -o "$dir/health.json" -w '%{http_code} %{time_total}\n' "${URL}api/v1/health"; }

# Freeze every server process (the postmaster and its children).
pm=$(head -n 1 "$dir/pg/postmaster.pid")
frozen="$pm $(pgrep -P "$pm" | tr '\n' ' ')"
kill -STOP $frozen

# Reads that need the database, in the background; health polled meanwhile.
t0=$(date +%s.%N)
( api -o "$dir/list.json" -w '%{http_code}' "${URL}api/v1/runs" > "$dir/list.code"; date +%s.%N > "$dir/list.t" ) &
lp=$!
( api -o "$dir/other.json" -w '%{http_code}' "${URL}api/v1/runs/$aid" > "$dir/other.code" ) &
op=$!
( "$FRINGE" run "$S" --server "$URL" --token-file "$T" -q > "$dir/post.out" 2>&1; echo $? > "$dir/post.rc" ) &
rp=$!
: > "$dir/health.times"
while kill -0 $lp 2>/dev/null || kill -0 $op 2>/dev/null || kill -0 $rp 2>/dev/null; do
  health >> "$dir/health.times"
  sleep 0.1
  [ "$($PY -c "print(int($(date +%s.%N) - $t0))")" -lt 60 ] || fail "requests still waiting after 60 s with the database frozen"
done
wait $lp $op $rp
list_s=$($PY -c "print(round($(cat "$dir/list.t") - $t0, 2))")
echo "frozen database: GET /runs answered $(cat "$dir/list.code") after $list_s s; health polled $(wc -l < "$dir/health.times") times," \
  "slowest $(sort -k2 -g "$dir/health.times" | tail -n 1 | cut -d' ' -f2) s"
[ "$(cat "$dir/list.code")" = 200 ] || fail "GET /runs with the database frozen: $(cat "$dir/list.code") $(cat "$dir/list.json")"
$PY -c 'import json,sys; b=json.load(open(sys.argv[1])); assert b.get("partial") is True and b["store"]["reachable"] is False, b' "$dir/list.json" \
  || fail "GET /runs says the list is partial: $(cat "$dir/list.json")"
$PY -c "import sys; sys.exit(0 if $list_s < 12 else 1)" || fail "GET /runs took $list_s s (deadline 2 s per wait)"
[ "$(cat "$dir/other.code")" = 503 ] || fail "another bench's run while the database is frozen: $(cat "$dir/other.code") $(cat "$dir/other.json")"
grep -q '"store_unreachable"' "$dir/other.json" || fail "503 names the cause: $(cat "$dir/other.json")"
[ "$(cat "$dir/post.rc")" = 0 ] || fail "a run posted while the database is frozen: $(cat "$dir/post.out")"
awk '$1 != 200 { bad = 1 } END { exit bad }' "$dir/health.times" || fail "health not 200: $(cat "$dir/health.times")"
# Health never waits for the database: its median is under 50 ms and no answer comes near the
# 2 s deadline (a loaded 2-core machine can delay any single answer by a few hundred ms).
$PY - "$dir/health.times" <<'PY' || fail "health answers while the database is frozen: $(sort -k2 -g "$dir/health.times" | tr '\n' ' ')"
import statistics, sys
t = [float(l.split()[1]) for l in open(sys.argv[1])]
print(f"health: {len(t)} answers, median {statistics.median(t) * 1000:.1f} ms, max {max(t) * 1000:.1f} ms")
sys.exit(0 if len(t) >= 3 and statistics.median(t) <= 0.05 and max(t) < 1.0 else 1)
PY

# Still frozen: health reports the store unreachable and the backlog (the posted run), at once;
# the same run again is still 503 (at once within 10 s of the failure, else after one connect
# timeout of 2 s).
for _ in $(seq 100); do
  health > /dev/null
  $PY -c 'import json,sys; s=json.load(open(sys.argv[1]))["store"]; sys.exit(0 if s["reachable"] is False and s["pending"] >= 1 else 1)' "$dir/health.json" && break
  sleep 0.1
done
$PY -c 'import json,sys; s=json.load(open(sys.argv[1]))["store"]; assert s["reachable"] is False and s["pending"] == 1 and s["error"] and "run store" in s["error"], s' "$dir/health.json" \
  || fail "health while frozen: $(cat "$dir/health.json")"
code=$(api -o /dev/null -w '%{http_code} %{time_total}' "${URL}api/v1/runs/$aid")
[ "${code%% *}" = 503 ] || fail "second look at another bench's run: $code"
$PY -c "import sys; sys.exit(0 if ${code##* } < 3 else 1)" || fail "the second 503 waited ${code##* } s"

# A reader on the frozen database: an error within the deadline, not a hang.
t1=$(date +%s.%N)
set +e; timeout 60 "$FRINGE" runs --store "$PGURI" > "$dir/runs.out" 2> "$dir/runs.err"; rc=$?; set -e
runs_s=$($PY -c "print(round($(date +%s.%N) - $t1, 2))")
echo "fringe runs on the frozen database: exit $rc after $runs_s s: $(head -c 300 "$dir/runs.err")"
[ $rc = 2 ] || fail "fringe runs on a frozen database exits 2, got $rc"
$PY -c "import sys; sys.exit(0 if $runs_s < 10 else 1)" || fail "fringe runs took $runs_s s"

thaw
for _ in $(seq 240); do
  [ "$(pg_sql "SELECT COUNT(*) FROM runs WHERE bench = 'bench-c'" 2>/dev/null)" = 1 ] && break
  sleep 0.25
done
[ "$(pg_sql "SELECT COUNT(*) FROM runs WHERE bench = 'bench-c'")" = 1 ] || fail "the run posted while frozen was forwarded after SIGCONT"
for _ in $(seq 100); do
  health > /dev/null
  $PY -c 'import json,sys; s=json.load(open(sys.argv[1]))["store"]; sys.exit(0 if s["reachable"] is True and s["pending"] == 0 else 1)' "$dir/health.json" && break
  sleep 0.1
done
$PY -c 'import json,sys; s=json.load(open(sys.argv[1]))["store"]; assert s["reachable"] is True and s["pending"] == 0, s' "$dir/health.json" \
  || fail "health after the thaw: $(cat "$dir/health.json")"
sleep 10.5  # the pause after the failed read: then the shared store is read again
code=$(api -o "$dir/other.json" -w '%{http_code}' "${URL}api/v1/runs/$aid")
[ "$code" = 200 ] || fail "another bench's run after the thaw: $code $(cat "$dir/other.json")"
kill -TERM $pid; wait $pid || fail "serve exits 0 on SIGTERM"; pid=
echo "postgres.freeze OK"
