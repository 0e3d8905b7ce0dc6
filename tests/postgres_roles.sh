#!/usr/bin/env bash
# The shared PostgreSQL store with real roles and real passwords (a throwaway PostgreSQL 15
# started here; password roles authenticate with scram-sha-256 on its unix socket).
# Least privilege: once the owner has created the tables, a role with only INSERT + SELECT
# forwards runs, and a SELECT-only role (also one whose transactions are read-only, as on a
# replica) lists runs and shows reports; none of them needs CREATE. A SELECT-only role on a
# database without the tables gets an error saying they are missing.
# Credentials: passwords holding '/', '%', '@' (raw, which libpq would misread, and
# percent-encoded), and one given as %70assword=, through the real CLI and the service, in
# real failures (wrong password, database down, forwarding pending): the password never
# appears in stdout, stderr, HTTP bodies, the service's log or any stored row.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
. "$SRC/tests/pg_lib.sh"
dir=$(mktemp -d); pid=
trap 'kill -9 $pid 2>/dev/null || true; pg_halt "$dir"; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
pg_start "$dir" || exit 1
export FRINGE_STORE_TIMEOUT_S=3
S="$dir/short.json"
$PY - "$SRC/fixtures/scenarios/fig10c-loopback.json" "$SRC/fixtures/encoders/paper-d2-analog.json" "$S" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s.update(duration_s=0.25, encoder=sys.argv[2])
json.dump(s, open(sys.argv[3], "w"))
PY
sock="host=$dir"

# ---- least privilege ---------------------------------------------------------------------
# The roles exist before the tables: the SELECT-only one finds none and says so.
pg_sql "CREATE ROLE ins LOGIN; CREATE ROLE ro LOGIN; CREATE ROLE replica LOGIN; ALTER ROLE replica SET default_transaction_read_only = on"
set +e; "$FRINGE" runs --store "postgresql:///postgres?$sock&user=ro" > "$dir/o" 2> "$dir/e"; rc=$?; set -e
[ $rc = 2 ] || fail "a SELECT-only role on a database without the tables: exit $rc"
grep -q "missing" "$dir/e" || fail "the error says the tables are missing: $(cat "$dir/e")"
# The owner creates them (its first run).
"$FRINGE" run "$S" --store "$PGURI" --data "$dir/owner" --bench owner -q || fail "the owner's run"
pg_sql "GRANT INSERT, SELECT ON runs, run_conflicts TO ins; GRANT SELECT ON runs, run_conflicts TO ro, replica"
"$FRINGE" run "$S" --store "postgresql:///postgres?$sock&user=ins" --data "$dir/ins" --bench ins-bench --forward-wait 5 > "$dir/o" 2> "$dir/e" \
  || fail "a run as the INSERT + SELECT role: $(cat "$dir/e")"
! grep -q "forwarding pending" "$dir/e" || fail "the INSERT + SELECT role forwards: $(cat "$dir/e")"
[ "$(pg_sql "SELECT COUNT(*) FROM runs WHERE bench = 'ins-bench' AND report IS NOT NULL")" = 1 ] || fail "the INSERT + SELECT role's run is stored"
# The same report again (a retry) is a no-op for it too, and a different one under that id a conflict.
iid=$(pg_sql "SELECT id FROM runs WHERE bench = 'ins-bench'")
for role in ro replica; do
  "$FRINGE" runs --store "postgresql:///postgres?$sock&user=$role" --json > "$dir/list.json" 2> "$dir/e" || fail "$role lists: $(cat "$dir/e")"
  $PY -c 'import json,sys; rs=json.load(open(sys.argv[1])); assert sorted(r["bench"] for r in rs) == ["ins-bench", "owner"], rs' "$dir/list.json" \
    || fail "$role lists both runs: $(cat "$dir/list.json")"
  "$FRINGE" runs --store "postgresql:///postgres?$sock&user=$role" --show "$iid" > "$dir/rep.json" 2> "$dir/e" || fail "$role shows a report: $(cat "$dir/e")"
  grep -q "$iid" "$dir/rep.json" || fail "$role: the report of $iid"
done
echo "least privilege: INSERT + SELECT forwards; SELECT-only and read-only roles list and show"

# ---- credentials -------------------------------------------------------------------------
PW='Sl/sh%zz@At%41pw'                 # raw: '/', a '%' without hex digits, '@', and %41
ENC='Sl%2Fsh%25zz%40At%2541pw'         # the same, percent-encoded
pg_sql "CREATE ROLE pw LOGIN PASSWORD '$PW'; GRANT INSERT, SELECT ON runs, run_conflicts TO pw"
# Password roles authenticate with scram-sha-256 (the rest stays trusted).
sed -i "1i local all pw scram-sha-256" "$dir/pg/pg_hba.conf"
pg_as "$PG_BIN/pg_ctl" -D "$dir/pg" reload > /dev/null
for _ in $(seq 50); do
  psql -w "postgresql:///postgres?$sock&user=pw" -XAtqc "SELECT 1" < /dev/null > /dev/null 2>&1 || break  # asks for the password now
  sleep 0.1
done
GOOD="postgresql://pw:$ENC@/postgres?$sock"
secrets=("$PW" "$ENC" "Sl/sh" "zz@At" "sh%zz" "WrongPass/9" "Wrong%2FPass" "Keyed/Secret%")
check_clean() {  # check_clean WHAT FILE...: no secret in any of them
  local what=$1; shift
  for s in "${secrets[@]}"; do
    if grep -F -q -- "$s" "$@"; then grep -F -n -- "$s" "$@" >&2; fail "$what prints a password ($s)"; fi
  done
}
# The encoded password works (and is not printed).
"$FRINGE" run "$S" --store "$GOOD" --data "$dir/pw" --bench pw-bench > "$dir/o1" 2> "$dir/e1" || fail "a run with the encoded password: $(cat "$dir/e1")"
[ "$(pg_sql "SELECT COUNT(*) FROM runs WHERE bench = 'pw-bench'")" = 1 ] || fail "the encoded password's run is stored"
"$FRINGE" runs --store "$GOOD" > "$dir/o2" 2> "$dir/e2" || fail "runs with the encoded password: $(cat "$dir/e2")"
# Raw '/', '%', '@' in the password: refused by name (libpq would connect elsewhere), exit 2.
set +e
"$FRINGE" runs --store "postgresql://pw:$PW@/postgres?$sock" > "$dir/o3" 2> "$dir/e3"; rc3=$?
"$FRINGE" run "$S" --store "postgresql://pw:Keyed/Secret%@/postgres?$sock" --data "$dir/pw" -q > "$dir/o4" 2> "$dir/e4"; rc4=$?
# Wrong passwords, in the userinfo and as %70assword= (libpq decodes the key).
"$FRINGE" runs --store "postgresql://pw:Wrong%2FPass@/postgres?$sock" > "$dir/o5" 2> "$dir/e5"; rc5=$?
"$FRINGE" runs --store "postgresql:///postgres?$sock&user=pw&%70assword=WrongPass/9" > "$dir/o6" 2> "$dir/e6"; rc6=$?
set -e
[ $rc3 = 2 ] && [ $rc4 = 2 ] || fail "a raw '/', '%' or '@' in the password: exit $rc3, $rc4: $(cat "$dir/e3" "$dir/e4")"
grep -q "%40" "$dir/e3" && grep -q "%2F\|%25" "$dir/e4" || fail "the refusal says what to encode: $(cat "$dir/e3" "$dir/e4")"
[ $rc5 = 2 ] && [ $rc6 = 2 ] || fail "a wrong password: exit $rc5, $rc6"
grep -q "password authentication failed" "$dir/e5" && grep -q "password authentication failed" "$dir/e6" \
  || fail "libpq's reason is kept: $(cat "$dir/e5" "$dir/e6")"
grep -q "%70assword=\*\*\*" "$dir/e6" || fail "the encoded key is redacted by name: $(cat "$dir/e6")"
# The database down: the run is kept, "forwarding pending" names the store without the password.
pg_halt "$dir"
"$FRINGE" run "$S" --store "$GOOD" --data "$dir/pw" --bench pw-bench --forward-wait 1 > "$dir/o7" 2> "$dir/e7" || fail "a run with the database down"
grep -q "forwarding pending" "$dir/e7" || fail "the run says forwarding is pending: $(cat "$dir/e7")"
"$FRINGE" run "$S" --store "postgresql:///postgres?$sock&user=pw&%70assword=Keyed/Secret%25" --data "$dir/pw2" --forward-wait 1 > "$dir/o8" 2> "$dir/e8" \
  || fail "a run with the database down (%70assword=)"
grep -q "forwarding pending" "$dir/e8" || fail "the run says forwarding is pending: $(cat "$dir/e8")"
# The service, database down: its banner, log, health and API answers.
"$FRINGE" serve --bind 127.0.0.1:0 --data "$dir/pw" --store "$GOOD" --bench pw-bench > "$dir/serve.out" 2> "$dir/serve.log" &
pid=$!
URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 100 0.1) || fail "fringe serve did not start: $(cat "$dir/serve.log")"
for _ in $(seq 100); do
  curl -sS --max-time 10 "${URL}api/v1/health" > "$dir/health.json"
  grep -q '"reachable":false' "$dir/health.json" && break
  sleep 0.1
done
grep -q '"reachable":false' "$dir/health.json" || fail "health says the store is unreachable: $(cat "$dir/health.json")"
curl -sS --max-time 30 "${URL}api/v1/runs" > "$dir/runs.json"
curl -sS --max-time 30 "${URL}api/v1/runs/run-of-another-bench" > "$dir/other.json"
grep -q store_unreachable "$dir/other.json" || fail "an unknown run with the store down: $(cat "$dir/other.json")"
kill -TERM $pid; wait $pid || true; pid=
pg_resume "$dir" || exit 1
for _ in $(seq 40); do  # the pending runs go with the next run
  "$FRINGE" run "$S" --store "$GOOD" --data "$dir/pw" --bench pw-bench -q > "$dir/o9" 2> "$dir/e9" && break
  sleep 0.25
done
check_clean "fringe run/runs/serve" "$dir"/o[1-9] "$dir"/e[1-9] "$dir/serve.out" "$dir/serve.log" "$dir/health.json" "$dir/runs.json" "$dir/other.json"
# Nothing stored carries it: the spool and the shared store.
for db in "$dir/pw/runs.db" "$dir/pw2/runs.db"; do
  [ -f "$db" ] || continue
  sqlite3 "$db" .dump > "$dir/dump.sql" 2>/dev/null || $PY -c 'import sqlite3,sys; print("\n".join(sqlite3.connect(sys.argv[1]).iterdump()))' "$db" > "$dir/dump.sql"
  check_clean "the spool $db" "$dir/dump.sql"
done
pg_as "$PG_BIN/pg_dump" -h "$dir" -U postgres postgres > "$dir/pg.sql"
grep -q "pw-bench" "$dir/pg.sql" || fail "the dump holds the runs"
check_clean "the shared store" "$dir/pg.sql"
echo "credentials: never printed (checked $(cat "$dir"/o[1-9] "$dir"/e[1-9] | wc -l) output lines, $(grep -c . "$dir/serve.log") log lines, HTTP bodies, both stores)"
echo "postgres.roles OK"
