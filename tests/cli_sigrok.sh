#!/usr/bin/env bash
# sigrok session files through the real executables: Debian's sigrok-cli (a third-party
# writer) turns fringe's CSV into .sr; fringe must score the .sr exactly like the CSV, and grade
# a DUT from the ABZ lines of a logic .sr made the same way (docs/capture-format.md, docs/abz.md).
set -euo pipefail
FRINGE="$1"; SRC="$2"
PY=/usr/bin/python3
command -v sigrok-cli >/dev/null || { echo "FAIL: sigrok-cli not installed (scripts/setup --test)" >&2; exit 1; }
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
expect_error() {  # expect_error PATTERN cmd...: exit 2 and stderr contains PATTERN
  local pat="$1"; shift
  set +e; msg=$("$@" 2>&1); rc=$?; set -e
  [ $rc -eq 2 ] || fail "expected exit 2, got $rc: $*"
  grep -q -- "$pat" <<<"$msg" || fail "expected '$pat' in: $msg"
}

"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/gen.csv" -q --samples 30000
rate=$($PY -c 'import json,sys; r=json.load(open(sys.argv[1]))["sample_rate_hz"]; assert r == int(r); print(int(r))' "$dir/gen.json")

# A .sr holds float32: make the CSV's columns float32-representable (sin/cos are already on
# the 16-bit ADC grid; theta_true/omega_true are not), so both files hold the same numbers.
$PY - "$dir/gen.csv" "$dir/cap.csv" <<'PY'
import struct, sys
f32 = lambda s: repr(struct.unpack('<f', struct.pack('<f', float(s)))[0])
src, dst = open(sys.argv[1]), open(sys.argv[2], 'w')
dst.write(next(src))
for line in src:
    c = line.rstrip('\n').split(',')
    dst.write(','.join([c[0]] + [f32(v) for v in c[1:]]) + '\n')
PY
cp "$dir/gen.json" "$dir/cap.json"
head -1 "$dir/cap.csv" | grep -qx 't,sin,cos,theta_true,omega_true' || fail "gen columns: $(head -1 "$dir/cap.csv")"
# column 1 (t) skipped: the session's time is k / samplerate
sigrok-cli -I "csv:column_formats=-,a,a,a,a:header=yes:samplerate=$rate" -i "$dir/cap.csv" -o "$dir/cap.sr"
cp "$dir/cap.json" "$dir/cap-sr.json"; mv "$dir/cap.sr" "$dir/cap-sr.sr"   # the sidecar beside it: x.sr + x.json
unzip -p "$dir/cap-sr.sr" metadata | grep -q '^analog1=sin$' || fail "sigrok-cli metadata: $(unzip -p "$dir/cap-sr.sr" metadata)"

for est in ekf-diffraction pll2; do
  "$FRINGE" estimate "$dir/cap.csv" --estimator "$est" --report "$dir/csv-$est.json" -o "$dir/csv-$est.est" -q
  "$FRINGE" estimate "$dir/cap-sr.sr" --estimator "$est" --report "$dir/sr-$est.json" -o "$dir/sr-$est.est" -q
  # identical scores, bounds and estimates, bit for bit
  $PY - "$dir/csv-$est.json" "$dir/sr-$est.json" <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
ea, eb = a["estimators"][0], b["estimators"][0]
for k in ("metrics", "bounds", "diagnosis"):
    assert ea[k] == eb[k], (k, ea[k], eb[k])
assert a["warnings"] == b["warnings"] and a["measurements"] == b["measurements"]
assert a["capture"]["encoder_source"] == b["capture"]["encoder_source"] and a["scenario"]["settle_s"] == b["scenario"]["settle_s"]
assert a["capture"]["samples"] == b["capture"]["samples"] == 30000
assert a["capture"]["sample_rate_hz"] == b["capture"]["sample_rate_hz"]
assert ea["metrics"]["scored"] == 20000 and ea["metrics"]["rms"]["rad"] > 0
PY
  cmp -s "$dir/csv-$est.est" "$dir/sr-$est.est" || fail "$est: estimates differ between the CSV and the .sr"
done
# without the sidecar the encoder comes from --encoder (the .sr has no place for it); scores
# are the same as the CSV's given the same profile
cp "$dir/cap-sr.sr" "$dir/bare.sr"
enc="$SRC/fixtures/encoders/paper-d2-duty1p6.json"
"$FRINGE" estimate "$dir/bare.sr" --estimator ekf-diffraction --encoder "$enc" --report "$dir/bare.report.json" -q
"$FRINGE" estimate "$dir/cap.csv" --estimator ekf-diffraction --encoder "$enc" --report "$dir/csvp.json" -q
$PY -c 'import json,sys; a,b=(json.load(open(p))["estimators"][0] for p in sys.argv[1:3]); assert a["metrics"]==b["metrics"] and a["bounds"]==b["bounds"]' "$dir/bare.report.json" "$dir/csvp.json"

# the channel map: a scope's channel names
sed '1s/.*/t,CH1,CH2,theta_true,omega_true/' "$dir/cap.csv" > "$dir/scope.csv"
sigrok-cli -I "csv:column_formats=-,a,a,a,a:header=yes:samplerate=$rate" -i "$dir/scope.csv" -o "$dir/scope.sr"
expect_error "no channel for column 'sin'" "$FRINGE" estimate "$dir/scope.sr" --estimator atan2 --report "$dir/x.json"
"$FRINGE" estimate "$dir/scope.sr" --channels sin=CH1,cos=CH2 --estimator atan2 --report "$dir/scope.report.json" -q
"$FRINGE" estimate "$dir/bare.sr" --estimator atan2 --report "$dir/bare-atan2.json" -q
$PY -c 'import json,sys; a,b=(json.load(open(p))["estimators"][0] for p in sys.argv[1:3]); assert a["metrics"]==b["metrics"]' "$dir/scope.report.json" "$dir/bare-atan2.json"

# hostile: a cut-off session, and a file that is not a ZIP: exit 2 naming the problem
head -c 20000 "$dir/bare.sr" > "$dir/cut.sr"
expect_error "cut.sr: not a sigrok session file" "$FRINGE" estimate "$dir/cut.sr" --estimator atan2 --report "$dir/x.json"
echo "t,sin,cos" > "$dir/fake.sr"
expect_error "fake.sr: not a sigrok session file" "$FRINGE" estimate "$dir/fake.sr" --estimator atan2 --report "$dir/x.json"

# ABZ: an ideal interpolator at factor N (A/B Gray code of floor(theta/step), Z one count wide
# at count 0 mod 4N) computed from the truth, written as logic columns by sigrok-cli.
N=16
$PY - "$dir/cap.csv" "$dir/abz.csv" $N <<'PY'
import math, sys
src, dst, N = open(sys.argv[1]), open(sys.argv[2], 'w'), int(sys.argv[3])
C = 4 * N; step = 2 * math.pi / C
gray = [(0, 0), (1, 0), (1, 1), (0, 1)]
next(src)
dst.write('t,sin,cos,theta_true,a,b,z\n')
for line in src:
    t, s, c, th, om = line.rstrip('\n').split(',')
    k = math.floor(float(th) / step)
    a, b = gray[k % 4]
    dst.write(','.join([t, s, c, th, str(a), str(b), '1' if k % C == 0 else '0']) + '\n')
PY
cp "$dir/cap.json" "$dir/abz.json"
sigrok-cli -I "csv:column_formats=-,a,a,a,l,l,l:header=yes:samplerate=$rate" -i "$dir/abz.csv" -o "$dir/abz-sr.sr"
cp "$dir/cap.json" "$dir/abz-sr.json"
unzip -p "$dir/abz-sr.sr" metadata | grep -q '^probe1=a$' || fail "logic channels: $(unzip -p "$dir/abz-sr.sr" metadata)"
"$FRINGE" estimate "$dir/abz.csv" --estimator atan2 --dut-interpolation $N --report "$dir/abz-csv.json" -q
"$FRINGE" estimate "$dir/abz-sr.sr" --estimator atan2 --dut-interpolation $N --report "$dir/abz-sr.report.json" > "$dir/abz.txt"
grep -q "dut (ABZ, 64 counts per cycle, reference index)" "$dir/abz.txt" || fail "dut summary: $(cat "$dir/abz.txt")"
$PY - "$dir/abz-csv.json" "$dir/abz-sr.report.json" $N <<'PY'
import json, math, sys
a, b = ([e for e in json.load(open(p))["estimators"] if e["label"] == "dut"][0] for p in sys.argv[1:3])
N = int(sys.argv[3]); step = 2 * math.pi / (4 * N)
assert a["metrics"] == b["metrics"], "the DUT scores differ between the CSV and the .sr"
ro, m = b["metrics"]["abz"], b["metrics"]
assert ro["illegal_transitions"] == 0 and ro["index_errors"] == 0 and ro["index_pulses"] >= 10, ro
# the quantisation of an ideal DUT: |e| <= step/2 (float32 truth adds < 1e-5 rad), rms step/sqrt(12)
assert m["max_abs"]["rad"] <= step / 2 + 1e-5, (m["max_abs"], step / 2)
assert abs(m["rms"]["rad"] / (step / math.sqrt(12)) - 1) < 0.05, (m["rms"], step / math.sqrt(12))
assert abs(m["mean"]["rad"]) < 0.05 * step, m["mean"]
PY

# the dut lane of a run: capture:X.sr?interpolation=N, limits on it; PASS, then FAIL on a glitch
$PY - "$SRC/fixtures/scenarios/paper-duty1p6.json" "$dir/run.json" "$dir/abz-sr.sr" $N <<'PY'
import json, os, sys
sc = json.load(open(sys.argv[1]))
sc["encoder"] = json.load(open(os.path.join(os.path.dirname(sys.argv[1]), sc["encoder"])))
sc["device"] = "capture:" + sys.argv[3] + "?interpolation=" + sys.argv[4]
sc["duration_s"] = 0.3
sc["estimators"] = [{"name": "atan2"}]
sc["limits"] = [{"estimator": "dut", "metric": "rms_rad", "max": 0.03},
                {"estimator": "dut", "metric": "abz_illegal_transitions", "max": 0}]
json.dump(sc, open(sys.argv[2], "w"))
PY
"$FRINGE" run "$dir/run.json" --report "$dir/rep.json" --no-db -q || fail "run on the ABZ capture did not pass (exit $?)"
$PY -c '
import json,sys; r=json.load(open(sys.argv[1]))
assert r["verdict"]=="PASS", r["verdict"]
d=[e for e in r["estimators"] if e["label"]=="dut"][0]
assert d["metrics"]["abz"]["illegal_transitions"]==0 and d["metrics"]["scored"]>10000, d["metrics"]["abz"]' "$dir/rep.json"
# one glitch: both lines flip at an edge in the middle
$PY - "$dir/abz.csv" "$dir/glitch.csv" <<'PY'
import sys
rows = open(sys.argv[1]).read().splitlines()
for i in range(15000, len(rows)):
    p, c = rows[i - 1].split(','), rows[i].split(',')
    if p[4:6] != c[4:6]:
        c[4], c[5] = str(1 - int(p[4])), str(1 - int(p[5]))
        rows[i] = ','.join(c); break
open(sys.argv[2], 'w').write('\n'.join(rows) + '\n')
PY
sigrok-cli -I "csv:column_formats=-,a,a,a,l,l,l:header=yes:samplerate=$rate" -i "$dir/glitch.csv" -o "$dir/glitch.sr"
cp "$dir/cap.json" "$dir/glitch.json"
sed -i "s#abz-sr.sr#glitch.sr#" "$dir/run.json"
set +e; "$FRINGE" run "$dir/run.json" --report "$dir/rep2.json" --no-db -q; rc=$?; set -e
[ $rc -eq 1 ] || fail "a glitched DUT must FAIL (exit 1), got $rc"
$PY -c '
import json,sys; r=json.load(open(sys.argv[1]))
m=[x for x in r["measurements"] if x["metric"]=="abz_illegal_transitions"][0]
assert m["outcome"]=="FAIL" and m["value"]>=1, m
assert any(w["code"]=="dut_illegal_transitions" for w in r["warnings"])' "$dir/rep2.json"
# the factor is required when the capture has A/B lines
sed -i "s#?interpolation=$N##" "$dir/run.json"
set +e; msg=$("$FRINGE" run "$dir/run.json" --report "$dir/rep3.json" --no-db -q 2>&1); rc=$?; set -e
[ $rc -eq 2 ] || fail "missing interpolation: expected exit 2, got $rc"
grep -q "interpolation=N" "$dir/rep3.json" || fail "missing interpolation not named: $msg"
echo "cli.sigrok: ok"
