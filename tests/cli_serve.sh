#!/usr/bin/env bash
# fringe serve through the real executable on 127.0.0.1: the stdlib Python client and
# `fringe run --server` get the same verdicts (exit 0 PASS, 1 FAIL); SIGTERM mid-run stores the run as interrupted with its
# partial report and exits 0; kill -9 mid-run, restart: the run is interrupted, completed
# reports are intact, the token is reused. Hostile requests: --allow-device and --allow-host
# decide which devices and Host names are answered; bytes that are not UTF-8 are a 400 and
# control characters in a scenario name are escaped in the log.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pid=
trap 'kill -9 $pid 2>/dev/null || true; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; [ -f "$dir/serve.log" ] && cat "$dir/serve.log" >&2; exit 1; }

start() {  # start the server on a free port (extra serve options as arguments); sets pid and URL
  : > "$dir/serve.log"  # fail() shows it
  "$FRINGE" serve --bind 127.0.0.1:0 --data "$dir/data" "$@" > "$dir/serve.out" 2> "$dir/serve.log" &
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
# wait (bounded: 60 s) until samples have been processed: under ASan on a loaded 2-core CI
# machine the run's set-up can take longer than any fixed sleep.
done_of() { api "${URL}api/v1/runs/$1" | $PY -c 'import json,sys; r=json.load(sys.stdin); print((r.get("progress") or {}).get("done", 0))'; }
for _ in $(seq 600); do [ "$(done_of "$id")" -gt 0 ] && break; sleep 0.1; done
[ "$(done_of "$id")" -gt 0 ] || fail "perf-1e7 processed nothing in 60 s"
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

# Without --allow-device/--allow-host: only loopback names and simulated devices.
code_of() { api -o "$dir/body.json" -w '%{http_code}' "$@"; }
scenario_on() {  # a short fig10c body on device $1, named $2
  $PY - "$SRC/fixtures/scenarios/fig10c-loopback.json" "$1" "${2:-fig10c}" <<'PY'
import json, sys
sc = json.load(open(sys.argv[1]))
sc.update(device=sys.argv[2], name=sys.argv[3], duration_s=0.05, settle_s=0.01, limits=[])
print(json.dumps({"scenario": sc}))
PY
}
post_device() { code_of -X POST -H "Authorization: Bearer $(cat "$T")" -d "$(scenario_on "$1")" "${URL}api/v1/runs"; }
err_code() { $PY -c 'import json,sys; print(json.load(open(sys.argv[1]))["error"]["code"])' "$dir/body.json"; }
[ "$(code_of -H 'Host: evil.example' "${URL}api/v1/runs")" = 421 ] && [ "$(err_code)" = misdirected_request ] || fail "foreign Host should be 421"
[ "$(code_of -H 'Host: bench.lab:8080' "${URL}")" = 421 ] || fail "foreign Host on a UI file should be 421"
[ "$(code_of -H 'Host: localhost' "${URL}api/v1/health")" = 200 ] || fail "Host localhost should be answered"
[ "$(post_device 'modbus+tcp://127.0.0.1:1502?board=generic-aio')" = 403 ] && [ "$(err_code)" = device_not_allowed ] \
  || fail "a Modbus board not allowed: 403, got $(cat "$dir/body.json")"
[ "$(code_of "${URL}api/v1/runs?%C3=1")" = 400 ] && [ "$(err_code)" = bad_encoding ] || fail "a query key that is not UTF-8: 400 bad_encoding"
[ "$(code_of "${URL}api/v1/health")" = 200 ] || fail "the service should still answer"
# CR/LF in a scenario name: one log line, escaped.
rid=$(api -X POST -H "Authorization: Bearer $(cat "$T")" -d "$(scenario_on loopback: $'evil\r\nFAKE-LOG-LINE')" "${URL}api/v1/runs" \
  | $PY -c 'import json,sys; print(json.load(sys.stdin)["id"])') || fail "run with CR/LF in its name"
for _ in $(seq 200); do [ "$(status_of "$rid")" = "done PASS" ] && break; sleep 0.05; done
for _ in $(seq 50); do grep -q "$rid" "$dir/serve.log" && break; sleep 0.05; done
grep -qF 'evil\r\nFAKE-LOG-LINE' "$dir/serve.log" || fail "the scenario name should be logged escaped"
! grep -q '^FAKE-LOG-LINE' "$dir/serve.log" || fail "a scenario name split the log"
kill -TERM $pid; wait $pid

# Bad patterns are refused at start.
set +e
"$FRINGE" serve --bind 127.0.0.1:0 --data "$dir/data" --allow-device 'file:/etc/passwd' > /dev/null 2> "$dir/bad.txt"; rc=$?
set -e
[ $rc -ne 0 ] && grep -q "not a device pattern" "$dir/bad.txt" || fail "--allow-device file:/etc/passwd should be refused, got $rc: $(cat "$dir/bad.txt")"

# With them: the allowed board and name are answered, others still refused.
start --allow-device 'modbus+tcp://127.0.0.1:15*' --allow-device 'usb:1209:*' --allow-host bench.lab
grep -q "devices clients may use: .*modbus+tcp://127.0.0.1:15\*, usb:1209:\*" "$dir/serve.out" || fail "start line names the allowed devices"
[ "$(code_of -H 'Host: bench.lab:8080' "${URL}api/v1/health")" = 200 ] || fail "--allow-host bench.lab should be answered"
[ "$(code_of -H 'Host: evil.example' "${URL}api/v1/health")" = 421 ] || fail "other names still 421"
[ "$(post_device 'modbus+tcp://127.0.0.1:1502?board=generic-aio')" = 201 ] || fail "allowed Modbus board: 201, got $(cat "$dir/body.json")"
[ "$(post_device 'modbus+tcp://127.0.0.1:22?board=generic-aio')" = 403 ] || fail "port 22 is not allowed"
[ "$(post_device 'modbus+tcp://127.0.0.1:1502?board=/etc/passwd')" = 400 ] || fail "a board path: 400"
! grep -q "root:" "$dir/body.json" || fail "a board path must not reveal the file"
[ "$(post_device 'modbus+rtu:/dev/ttyUSB0')" = 403 ] || fail "serial ports not allowed here"
kill -TERM $pid; wait $pid
echo "cli.serve: ok"
