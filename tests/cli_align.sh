#!/usr/bin/env bash
# Output and input instruments on their own clocks through the real executable: the
# loopback-two-clocks fixture passes with its alignment measured and limited; an unalignable
# input and a bad input URI end as ERROR (exit 2) naming why.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
S="$SRC/fixtures/scenarios"

"$FRINGE" run "$S/loopback-two-clocks.json" --data "$dir/data" --report "$dir/r.json" --junit "$dir/r.xml" -q \
  || fail "loopback-two-clocks should pass"
$PY - "$dir" <<'PY'
import json, sys, xml.etree.ElementTree as ET
d = sys.argv[1]
r = json.load(open(d + "/r.json"))
assert r["verdict"] == "PASS", r["verdict"]
a = r["alignment"]
assert a["ok"] and abs(a["delay_s"] - 3.21e-4) < 1e-8 and abs(a["clock_offset_ppm"] - 25) < 0.01, a
assert abs(a["channels"]["sin"]["gain"] - 0.95) < 1e-3 and abs(a["channels"]["cos"]["offset_v"] - 0.002) < 1e-4, a["channels"]
run = [m for m in r["measurements"] if m["estimator"] == "run"]
assert [m["metric"] for m in run] == ["alignment_delay_s", "clock_offset_ppm", "alignment_residual"], run
assert all(m["outcome"] == "PASS" for m in run), run
assert r["scenario"]["device"]["output"] == r["scenario"]["device"]["input"]
cases = ET.parse(d + "/r.xml").getroot().find("testsuite").findall("testcase")
assert len(cases) == len(r["measurements"]), len(cases)
PY
"$FRINGE" runs --data "$dir/data" | grep -q "loopback-two-clocks" || fail "the run is not in the history"

# The input sees noise only: ERROR naming the alignment, exit 2.
set +e
"$FRINGE" run "$S/loopback-two-clocks.json" --data "$dir/data" --report "$dir/e.json" -q \
  --device "loopback:?own_clock=1&gain=0&noise_v=1e-3" 2>"$dir/err"
code=$?
set -e
[ "$code" = 2 ] || fail "unalignable input: exit $code, expected 2"
grep -q "alignment not confident: no correlation" "$dir/err" || { cat "$dir/err"; fail "the error does not say why"; }
$PY -c "import json,sys; r=json.load(open(sys.argv[1])); assert r['verdict']=='ERROR' and r['alignment']['ok'] is False" "$dir/e.json"

# A bad input URI is named by its field.
$PY - "$S/loopback-two-clocks.json" "$dir/bad.json" <<'PY'
import json, sys
j = json.load(open(sys.argv[1]))
j["device"]["input"] = "loopback:?own_clock=1&adc_bitz=3"
json.dump(j, open(sys.argv[2], "w"))
PY
set +e
"$FRINGE" run "$dir/bad.json" --data "$dir/data" -q 2>"$dir/err2"
code=$?
set -e
[ "$code" = 2 ] || fail "bad input URI: exit $code, expected 2"
grep -q "device.input.adc_bitz" "$dir/err2" || { cat "$dir/err2"; fail "the error does not name device.input.adc_bitz"; }
echo "cli.align: ok"
