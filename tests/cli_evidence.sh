#!/usr/bin/env bash
# No verdict without evidence, through the real executables: `fringe run` FAILs a run with
# nothing scored and refuses an undersampled scenario (exit 2), `fringe estimate` says "no
# scored samples" instead of printing zeros, a faulted external child FAILs, a known 8x
# defect comes back in the report, and over HTTP the undersampled scenario is a 400 naming
# the field. Warnings reach the CLI output, JUnit properties and the HTML report.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"; DEFECTS="$3"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pid=
trap 'kill -9 $pid 2>/dev/null || true; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; [ -f "$dir/serve.log" ] && cat "$dir/serve.log" >&2; exit 1; }
run_rc() { set +e; "$@" > "$dir/out.txt" 2>&1; rc=$?; set -e; }

# A scenario of the user's own, varied per case by a Python one-liner.
scenario() {  # scenario OUT.json PYTHON-EXPR-ON-s
  $PY - "$1" "$2" "$SRC" <<'PY'
import json, sys
out, expr, src = sys.argv[1], sys.argv[2], sys.argv[3]
s = {"name": "mine", "encoder": json.load(open(src + "/fixtures/encoders/ideal.json")),
     "motion": {"kind": "constant", "electrical_freq_hz": 100.0}, "sample_rate_hz": 100000,
     "duration_s": 0.3, "settle_s": 0.1, "seed": 1, "device": "loopback:?dac_bits=16&adc_bits=16",
     "estimators": [{"name": "atan2"}],
     "limits": [{"estimator": "*", "metric": "rms_rad", "max": 4e-5},
                {"estimator": "*", "metric": "slipped_samples", "max": 0}]}
s["encoder"]["adc"]["bits"] = 0
exec(expr)
json.dump(s, open(out, "w"))
PY
}

# 1. settle >= duration: refused, naming the key (exit 2)
scenario "$dir/s1.json" 's["duration_s"] = 0.1'
run_rc "$FRINGE" run "$dir/s1.json" --no-db
[ $rc -eq 2 ] || fail "settle = duration: exit $rc"; grep -q "settle_s" "$dir/out.txt" || fail "names settle_s: $(cat "$dir/out.txt")"

# 2. 50 scored samples: the rms limit alone would PASS; the evidence FAILs it (exit 1)
scenario "$dir/s2.json" 's["duration_s"] = 0.1005'
run_rc "$FRINGE" run "$dir/s2.json" --no-db --junit "$dir/s2.xml" --html "$dir/s2.html"
[ $rc -eq 1 ] || fail "50 scored samples: exit $rc: $(cat "$dir/out.txt")"
grep -q "FAIL     atan2 scored_samples = 50 samples (limit >= 1000, evidence)" "$dir/out.txt" || fail "evidence line: $(cat "$dir/out.txt")"
grep -q 'name="scored_samples"' "$dir/s2.xml" || fail "JUnit testcase for the evidence"
grep -q "scored samples" "$dir/s2.html" || fail "HTML evidence column"

# 3. undersampled (2048 lines at 3000 rpm, 200 kHz): exit 2 naming the field and the cause
scenario "$dir/s3.json" 's["encoder"]["lines_per_rev"] = 2048; s["motion"] = {"kind": "constant", "velocity_rad_s": 314.159265}; s["sample_rate_hz"] = 200000'
run_rc "$FRINGE" run "$dir/s3.json" --no-db
[ $rc -eq 2 ] || fail "undersampled: exit $rc"
grep -q "sample_rate_hz: undersampled: 1.95[0-9]* (< 2) samples per electrical cycle" "$dir/out.txt" || fail "undersampled message: $(cat "$dir/out.txt")"

# 4. warnings travel: double quantisation (encoder ADC + device ADC) in the CLI, JUnit, HTML
scenario "$dir/s4.json" 's["encoder"]["adc"]["bits"] = 16; s["limits"] = []'
run_rc "$FRINGE" run "$dir/s4.json" --no-db --junit "$dir/s4.xml" --html "$dir/s4.html" --report "$dir/s4.report.json"
[ $rc -eq 0 ] || fail "double quantisation still runs: exit $rc: $(cat "$dir/out.txt")"
grep -q "warning: the encoder profile has its own 16-bit ADC" "$dir/out.txt" || fail "CLI warning: $(cat "$dir/out.txt")"
grep -q 'property name="warning" value="double_quantisation' "$dir/s4.xml" || fail "JUnit warning property"
grep -q 'id="warnings"' "$dir/s4.html" || fail "HTML warnings"

# 5. an external child whose every sample is invalid FAILs (it PASSed with rms 0 before)
scenario "$dir/s5.json" "s['estimators'] = [{'name': 'external', 'label': 'fw', 'params': {'command': '$DEFECTS invalid'}}]"
run_rc "$FRINGE" run "$dir/s5.json" --no-db
[ $rc -eq 1 ] || fail "all-invalid child: exit $rc: $(cat "$dir/out.txt")"
grep -q "FAIL     fw valid_fraction = 0" "$dir/out.txt" || fail "valid fraction line: $(cat "$dir/out.txt")"
grep -q "FAIL     fw rms_rad = not measured" "$dir/out.txt" || fail "rms not measured: $(cat "$dir/out.txt")"

# 6. a firmware-like 8x error of 3e-3 rad comes back from the report within 5 %
scenario "$dir/s6.json" "s['duration_s'] = 0.5; s['estimators'] = [{'name': 'external', 'label': 'fw', 'params': {'command': '$DEFECTS h8 3e-3', 'model': 'memoryless'}}]; s['limits'] = [{'estimator': 'fw', 'metric': 'harmonic_8x_rad', 'max': 3.15e-3, 'min': 2.85e-3}, {'estimator': 'fw', 'metric': 'efficiency', 'min': 1e-4}]"
run_rc "$FRINGE" run "$dir/s6.json" --no-db --report "$dir/r6.json"
[ $rc -eq 0 ] || fail "8x child within limits: exit $rc: $(cat "$dir/out.txt")"
$PY - "$dir/r6.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
m = r["estimators"][0]["metrics"]
a = {h["order"]: h["amplitude"]["rad"] for h in m["harmonics"]}
assert len(a) == 16, a
assert abs(a[8] - 3e-3) < 0.05 * 3e-3, a[8]
assert m["harmonic_analysis"]["power_fraction"] > 0.9, m["harmonic_analysis"]
assert r["estimators"][0]["bounds"]["efficiency"] is not None
PY

# 7. fringe estimate on a 99-sample capture: "no scored samples", no zeros, exit 1
"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/short.csv" -q --samples 99
set +e; "$FRINGE" estimate "$dir/short.csv" --estimator atan2 --report "$dir/e.json" > "$dir/out.txt"; rc=$?; set -e
[ $rc -eq 1 ] || fail "estimate with nothing scored exited $rc, not 1"
grep -q "no scored samples: 99 samples" "$dir/out.txt" || fail "estimate: $(cat "$dir/out.txt")"
if grep -q "rms 0.000e+00" "$dir/out.txt"; then fail "estimate printed a zero rms"; fi
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); m=r["estimators"][0]["metrics"]; assert m["rms"] is None and m["scored"] == 0 and r["verdict"] == "FAIL"' "$dir/e.json"

# 8. over HTTP: the undersampled scenario is a 400 naming the field; the evidence FAIL is a FAIL
"$FRINGE" serve --bind 127.0.0.1:0 --data "$dir/data" > "$dir/serve.out" 2> "$dir/serve.log" &
pid=$!
URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 100 0.1) || fail "fringe serve did not start"
T=$(cat "$dir/data/token")
$PY - "$URL" "$T" "$dir/s3.json" "$dir/s2.json" <<'PY'
import json, sys, time, urllib.request, urllib.error
url, token, under, few = sys.argv[1:5]
def post(path, body):
    req = urllib.request.Request(url + "api/v1/" + path, data=json.dumps(body).encode(),
                                 headers={"Authorization": "Bearer " + token, "Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, json.load(r)
    except urllib.error.HTTPError as e:
        return e.code, json.load(e)
code, body = post("runs", {"scenario": json.load(open(under))})
assert code == 400, (code, body)
assert body["error"]["field"] == "scenario.sample_rate_hz" and "undersampled" in body["error"]["message"], body
code, body = post("runs", {"scenario": json.load(open(few))})
assert code == 201, (code, body)
for _ in range(200):
    with urllib.request.urlopen(url + "api/v1/runs/" + body["id"], timeout=10) as r:
        run = json.load(r)
    if run["status"] not in ("queued", "running"):
        break
    time.sleep(0.05)
assert run["verdict"] == "FAIL", run
with urllib.request.urlopen(url + "api/v1/runs/" + body["id"] + "/report.json", timeout=10) as r:
    rep = json.load(r)
ev = [m for m in rep["measurements"] if m.get("implicit")]
assert any(m["metric"] == "scored_samples" and m["outcome"] == "FAIL" for m in ev), ev
PY
echo "cli.evidence: ok"
