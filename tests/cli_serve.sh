#!/usr/bin/env bash
# fringe serve through the real executable on 127.0.0.1: the stdlib Python client and
# `fringe run --server` get the same verdicts (exit 0 PASS, 1 FAIL); SIGTERM mid-run stores the run as interrupted with its
# partial report and exits 0; kill -9 mid-run, restart: the run is interrupted, completed
# reports are intact, the token is reused.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pid=
trap 'kill -9 $pid 2>/dev/null || true; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; [ -f "$dir/serve.log" ] && cat "$dir/serve.log" >&2; exit 1; }

start() {  # start the server on a free port; sets pid and URL
  : > "$dir/serve.log"  # fail() shows it
  "$FRINGE" serve --bind 127.0.0.1:0 --data "$dir/data" > "$dir/serve.out" 2> "$dir/serve.log" &
  pid=$!
  URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 100 0.1) || fail "fringe serve did not start"
}
api() { curl -sS --max-time 10 "$@"; }
status_of() { api "${URL}api/v1/runs/$1" | $PY -c 'import json,sys; r=json.load(sys.stdin); print(r["status"], r["verdict"] or "")'; }

start
grep -q "API token (printed this once" "$dir/serve.out" || fail "first start prints the token"
[ "$(stat -c %a "$dir/data/token")" = 600 ] || fail "token file mode"
T="$dir/data/token"

$PY "$SRC/scripts/fringe_remote.py" "$URL" fig10c-loopback --token-file "$T" --junit "$dir/j.xml" > "$dir/ok.txt" || fail "fig10c over HTTP should PASS"
grep -q "PASS (done)" "$dir/ok.txt" || fail "verdict line: $(cat "$dir/ok.txt")"
grep -q "<testsuites" "$dir/j.xml" || fail "JUnit from the script"
set +e
$PY "$SRC/scripts/fringe_remote.py" "$URL" ci-failing --token-file "$T" > "$dir/f.txt"; rc=$?
set -e
[ $rc -eq 1 ] || fail "ci-failing over HTTP should exit 1, got $rc"
grep -q "FAIL" "$dir/f.txt" || fail "FAIL verdict line"
# fringe run --server: the scenario is read here, run by the service, its report fetched. The
# same seed gives the same scenario, metrics and measurements as a local run.
"$FRINGE" run "$SRC/fixtures/scenarios/fig10c-loopback.json" --server "$URL" --token-file "$T" \
  --report "$dir/rr.json" --junit "$dir/rj.xml" --html "$dir/rh.html" > "$dir/rr.txt" || fail "fringe run --server should PASS"
grep -q "fig10c-loopback PASS (done)" "$dir/rr.txt" || fail "run --server verdict line: $(cat "$dir/rr.txt")"
"$FRINGE" run "$SRC/fixtures/scenarios/fig10c-loopback.json" --no-db -q --report "$dir/lr.json" || fail "fig10c locally"
$PY - "$dir/rr.json" "$dir/lr.json" <<'PY' || fail "run --server report"
import json, sys
r, l = (json.load(open(p)) for p in sys.argv[1:3])
assert r["scenario"] == l["scenario"], "the service ran a different scenario"
assert [e["metrics"] for e in r["estimators"]] == [e["metrics"] for e in l["estimators"]], "metrics differ"
assert r["measurements"] == l["measurements"] and r["verdict"] == "PASS", r["verdict"]
PY
grep -q "<testsuites" "$dir/rj.xml" || fail "run --server JUnit"
grep -qi "<html" "$dir/rh.html" || fail "run --server HTML"
rid=$($PY -c 'import json,sys; print(json.load(open(sys.argv[1]))["id"])' "$dir/rr.json")
[ "$(status_of "$rid")" = "done PASS" ] || fail "run --server: the run is in the service's history"
set +e
"$FRINGE" run "$SRC/fixtures/scenarios/ci-failing.json" --server "$URL" --token-file "$T" -q; rc=$?
[ $rc -eq 1 ] || fail "run --server of a FAIL should exit 1, got $rc"
"$FRINGE" run "$SRC/fixtures/scenarios/ci-failing.json" --server "$URL" --token-file /dev/null -q 2> "$dir/e401.txt"; rc=$?
[ $rc -eq 2 ] && grep -q "HTTP 401" "$dir/e401.txt" || fail "run --server without a token: exit 2 naming 401, got $rc: $(cat "$dir/e401.txt")"
"$FRINGE" run "$SRC/fixtures/scenarios/ci-failing.json" --server "http://127.0.0.1:1" --token-file "$T" -q 2> "$dir/eref.txt"; rc=$?
[ $rc -eq 2 ] && grep -q "127.0.0.1:1/.*refused" "$dir/eref.txt" || fail "run --server, nobody listening: exit 2 naming the server, got $rc: $(cat "$dir/eref.txt")"
set -e

done_id=$(api "${URL}api/v1/runs?outcome=PASS" | $PY -c 'import json,sys; print(json.load(sys.stdin)["runs"][0]["id"])')
api "${URL}api/v1/runs/$done_id/report.json" > "$dir/before.json"

# curl, as in the README
code=$(api -o /dev/null -w '%{http_code}' -X POST -H "Authorization: Bearer wrong-token-0000000000" -d '{"fixture":"fig10c-loopback"}' "${URL}api/v1/runs")
[ "$code" = 403 ] || fail "wrong token should be 403, got $code"

# SIGTERM mid-run: the run is stored as interrupted with a partial report; exit 0.
id=$(api -X POST -H "Authorization: Bearer $(cat "$T")" -d '{"fixture":"perf-1e7"}' "${URL}api/v1/runs" | $PY -c 'import json,sys; print(json.load(sys.stdin)["id"])')
for _ in $(seq 100); do [ "$(status_of "$id")" = "running " ] && break; sleep 0.05; done
sleep 0.3
kill -TERM $pid
set +e; wait $pid; rc=$?; set -e
[ $rc -eq 0 ] || fail "serve should exit 0 on SIGTERM, got $rc"
start
grep -q "API token: in" "$dir/serve.out" || fail "second start reuses the token without printing it"
[ "$(status_of "$id")" = "interrupted ABORTED" ] || fail "SIGTERM: run should be interrupted, is $(status_of "$id")"
api "${URL}api/v1/runs/$id/report.json" | $PY -c '
import json,sys; r=json.load(sys.stdin)
assert r["status"] == "interrupted" and 0 < r["samples"]["processed"] < r["samples"]["planned"], r["samples"]' || fail "partial report"

# kill -9 mid-run, restart: interrupted, and the completed report is byte-identical.
id2=$(api -X POST -H "Authorization: Bearer $(cat "$T")" -d '{"fixture":"perf-1e7"}' "${URL}api/v1/runs" | $PY -c 'import json,sys; print(json.load(sys.stdin)["id"])')
for _ in $(seq 100); do [ "$(status_of "$id2")" = "running " ] && break; sleep 0.05; done
kill -9 $pid; wait $pid 2>/dev/null || true
start
[ "$(status_of "$id2")" = "interrupted ABORTED" ] || fail "kill -9: run should be interrupted, is $(status_of "$id2")"
api "${URL}api/v1/runs/$id2/report.json" | grep -q '"not_finished"' || fail "a killed run has no report (409)"
api "${URL}api/v1/runs/$done_id/report.json" > "$dir/after.json"
cmp -s "$dir/before.json" "$dir/after.json" || fail "completed report changed across a kill -9"
kill -TERM $pid; wait $pid
echo "cli.serve: ok"
