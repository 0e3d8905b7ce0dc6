#!/usr/bin/env bash
# fringe estimate through the real executable: scores with truth, estimates only without,
# exit 2 with a message naming the problem on bad input.
set -euo pipefail
FRINGE="$1"; SRC="$2"
PY=/usr/bin/python3
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
expect_error() {  # expect_error PATTERN cmd...: exit 2 and stderr contains PATTERN
  local pat="$1"; shift
  set +e; msg=$("$@" 2>&1); rc=$?; set -e
  [ $rc -eq 2 ] || fail "expected exit 2, got $rc: $*"
  grep -q -- "$pat" <<<"$msg" || fail "expected '$pat' in: $msg"
}

"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/cap.csv" -q --samples 30000

# --list names every estimator, as text and JSON
"$FRINGE" estimate --list > "$dir/list.txt"; grep -q "^ekf-diffraction" "$dir/list.txt" || fail "--list"
"$FRINGE" estimate --list --json | $PY -c 'import json,sys; n=[e["name"] for e in json.load(sys.stdin)]; assert "closed-loop" in n and "external" in n, n'

# with truth: a scored report; ekf-diffraction at the ~2e-5 rad bound
"$FRINGE" estimate "$dir/cap.csv" --estimator ekf-diffraction -o "$dir/est.csv" --report "$dir/r.json"
[ "$(head -1 "$dir/est.csv")" = "t,theta_rad,omega_rad_s,valid" ] || fail "estimates header"
[ "$(wc -l < "$dir/est.csv")" -eq 30001 ] || fail "estimates rows"
$PY - "$dir/r.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
assert r["schema"] == "fringe.report" and r["schema_version"] == 3 and r["status"] == "done"
m, b = r["estimators"][0]["metrics"], r["estimators"][0]["bounds"]
assert m["scored"] == 20000, m["scored"]
assert 5e-6 < m["rms"]["rad"] < 4e-5, m["rms"]
assert abs(m["rms"]["percent_period"] - m["rms"]["rad"] / 6.283185307179586 * 100) < 1e-12
assert abs(m["rms"]["arcsec_mech"] - m["rms"]["rad"] / 1024 * 206264.80624709636) < 1e-9
assert len(m["harmonics"]) == 16 and m["slipped_samples"] == 0
assert m["evidence"]["scored_samples"] == 20000 and m["evidence"]["valid_fraction"] == 1.0
assert b["efficiency_against"] == "pcrb_noise_only" and 0.3 < b["efficiency"] < 1.5, b
assert r["capture"]["encoder_source"] == "capture metadata" and r["capture"]["samples"] == 30000 and r["capture"]["has_truth"] is True
assert r["device"]["driver"] == "capture" and r["scenario"]["device"].startswith("capture:")
assert r["verdict"] == "PASS" and r["capture"]["not_scored"] is None
PY

# parameters through --param, an explicit profile through --encoder
"$FRINGE" estimate "$dir/cap.csv" --estimator pll2 --param natural_freq_hz=50 --param damping=1 \
  --encoder "$SRC/fixtures/encoders/paper-d2-duty1p6.json" --report "$dir/p.json" -q
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); assert r["estimators"][0]["params"]["natural_freq_hz"]==50 and r["capture"]["encoder_source"]=="profile file"' "$dir/p.json"

# without truth: estimates only
cut -d, -f1-3 "$dir/cap.csv" > "$dir/notruth.csv"
"$FRINGE" estimate "$dir/notruth.csv" --estimator atan2 -o "$dir/e2.csv" --report "$dir/n.json" > "$dir/n.txt"; grep -q "estimates only" "$dir/n.txt" || fail "no-truth summary"
[ "$(wc -l < "$dir/e2.csv")" -eq 30001 ] || fail "no-truth rows"
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); assert r["capture"]["has_truth"] is False and r["verdict"] is None and r["measurements"] == [] and "no theta_true" in r["capture"]["not_scored"] and r["estimators"][0]["metrics"]["scored"] == 0' "$dir/n.json"

# without truth, graded against an interface profile: the bands are the measurements and the verdict
"$FRINGE" estimate "$dir/notruth.csv" --estimator atan2 --interface "$SRC/fixtures/interfaces/1vpp.json" --report "$dir/ni.json" > "$dir/ni.txt"
grep -q "signal bands .*graded against 1 Vpp" "$dir/ni.txt" && grep -q "^verdict [A-Z]*: the signals graded against 1 Vpp" "$dir/ni.txt" && grep -q "A/B .*\[.*|.*\] *spec 0.8..1.25, mounting 0.9..1.1: " "$dir/ni.txt" || fail "the signal bands block"
$PY - "$dir/ni.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
ms = r["measurements"]
assert len(ms) == 6 and all(m["estimator"] == "run" and m["interface"] == "1 Vpp" for m in ms), ms
worst = "FAIL" if any(m["outcome"] == "FAIL" for m in ms) else "MARGINAL" if any(m["outcome"] == "MARGINAL" for m in ms) else "PASS"
assert r["verdict"] == worst and "interface profile" in r["capture"]["not_scored"], (r["verdict"], worst)
PY
# the same capture through fringe run (a capture: device, no motion): its summary gives the self-referenced error, not "no scored samples"
$PY - "$dir/cap.json" "$dir/notruth.csv" "$SRC/fixtures/encoders/ideal.json" > "$dir/ntrun.json" <<'PY'
import json, sys
fs = json.load(open(sys.argv[1]))["sample_rate_hz"]
print(json.dumps({"name": "no-truth", "encoder": sys.argv[3], "sample_rate_hz": fs, "duration_s": 30000 / fs, "settle_s": 0.05,
                  "device": "capture:" + sys.argv[2], "estimators": [{"name": "atan2"}], "limits": [{"estimator": "atan2", "metric": "self_ref_rms_rad", "max": 1}]}))
PY
"$FRINGE" run "$dir/ntrun.json" --no-db > "$dir/ntrun.txt" || fail "a capture: run without truth: exit $? $(cat "$dir/ntrun.txt")"
grep -q "^  atan2 *self-referenced (no truth) rms .* rad (95 % " "$dir/ntrun.txt" && ! grep -q "no scored samples" "$dir/ntrun.txt" || fail "run summary without truth: $(cat "$dir/ntrun.txt")"

# the same as HTML and JUnit: the signal page with a gauge a band, a testcase a band
"$FRINGE" estimate "$dir/notruth.csv" --estimator atan2 --interface "$SRC/fixtures/interfaces/1vpp.json" --html "$dir/ni.html" --junit "$dir/ni.xml" -q
[ "$(grep -o 'class="gauge"' "$dir/ni.html" | wc -l)" -eq 6 ] && grep -q 'id="signal-page"' "$dir/ni.html" || fail "estimate --html: the signal page"
[ "$(grep -o "<testcase" "$dir/ni.xml" | wc -l)" -eq 6 ] && [ "$(grep -o "<property name=\"grade\"" "$dir/ni.xml" | wc -l)" -eq 6 ] && ! grep -q marginal_fraction "$dir/ni.xml" || fail "estimate --junit: a testcase a band, its grade"
# a band as wide as a double allows: no crash, no NaN in the HTML (found by a trial: the gauge's width overflowed)
printf '{"name": "wide", "bands": {"signal_vpp_a_v": {"spec": [-1e308, 1e308]}, "signal_ab_ratio": {"spec": [0, 1e308]}}}' > "$dir/wide.json"
"$FRINGE" estimate "$dir/notruth.csv" --estimator atan2 --interface "$dir/wide.json" --html "$dir/wide.html" > "$dir/wide.txt" || fail "a wide band: exit $?"
grep -q "A pp .*spec -1e+308..1e+308: within specification" "$dir/wide.txt" || fail "a wide band's line: $(cat "$dir/wide.txt")"
! grep -q 'nan\|inf"' "$dir/wide.html" || fail "a wide band: NaN or inf in the HTML"
expect_error "html: .*notruth.csv is the capture" "$FRINGE" estimate "$dir/notruth.csv" --estimator atan2 --html "$dir/notruth.csv"
printf '{"name": "x", "bands": {"signal_vpp_a_v": {"spec": [2, 1]}}}' > "$dir/badif.json"
expect_error "interface.bands.signal_vpp_a_v.*badif.json" "$FRINGE" estimate "$dir/notruth.csv" --estimator atan2 --interface "$dir/badif.json"

# bad input: exit 2, the problem named
expect_error "unknown estimator 'ekf-magic'" "$FRINGE" estimate "$dir/cap.csv" --estimator ekf-magic -o "$dir/x.csv"
expect_error "params.natural_freq_hz" "$FRINGE" estimate "$dir/cap.csv" --estimator pll2 --param natural_freq_hz=-3 -o "$dir/x.csv"
expect_error "params.bandwidth" "$FRINGE" estimate "$dir/cap.csv" --estimator pll2 --param bandwidth=3 -o "$dir/x.csv"
expect_error "params.kappa" "$FRINGE" estimate "$dir/notruth.csv" --estimator ekf-diffraction -o "$dir/x.csv"
sed '5s/^\([^,]*\),[^,]*,/\1,nan,/' "$dir/notruth.csv" > "$dir/nan.csv"
expect_error "nan.csv:5" "$FRINGE" estimate "$dir/nan.csv" --estimator atan2 -o "$dir/x.csv"
# a .fcap whose header lists sin twice (sin, cos, sin, omega_true: same frame size) once
# overflowed a buffer in the estimator; now exit 2 naming the column
"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/x.fcap" -q --samples 64
$PY - "$dir/x.fcap" "$dir/dup.fcap" <<'PY'
import json, struct, sys
b = open(sys.argv[1], "rb").read()
n = struct.unpack("<I", b[8:12])[0]
h = json.loads(b[12:12 + n])
assert [c["name"] for c in h["columns"]] == ["sin", "cos", "theta_true", "omega_true"], h["columns"]
h["columns"][2] = {"name": "sin", "type": "f64", "unit": "V"}
hb = json.dumps(h).encode()
open(sys.argv[2], "wb").write(b[:8] + struct.pack("<I", len(hb)) + hb + b[12 + n:])
PY
expect_error "dup.fcap: header.columns\[2\]: duplicate column 'sin'" "$FRINGE" estimate "$dir/dup.fcap" --estimator atan2 -o "$dir/x.csv"
expect_error "\-q prints nothing" "$FRINGE" estimate "$dir/cap.csv" --estimator atan2 -q
expect_error "the shell found no such command" "$FRINGE" estimate "$dir/cap.csv" --estimator external --param "command=$dir/no-such-firmware" -o "$dir/x.csv"
expect_error "no output for" "$FRINGE" estimate "$dir/cap.csv" --estimator external --param "command=sleep 20" --param timeout_s=0.3 -o "$dir/x.csv"
# the summary says when an estimator lost lock or re-learnt: the signal x10 from the middle on
awk -F, 'BEGIN{OFS=","} NR>15001{$2*=10;$3*=10} {print}' "$dir/cap.csv" > "$dir/jump.csv"; cp "$dir/cap.json" "$dir/jump.json"
"$FRINGE" estimate "$dir/jump.csv" --estimator ekf-diffraction --report "$dir/j.json" > "$dir/j.txt"
grep -Eq "^ekf-diffraction: loss of lock [1-9][0-9]* times \([1-9][0-9]* samples invalid" "$dir/j.txt" || fail "no loss-of-lock line: $(cat "$dir/j.txt")"
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); l=r["estimators"][0]["state"]["loss_of_lock"]; assert l["events"]>0 and r["estimators"][0]["metrics"]["evidence"]["valid_fraction"]<0.5, l' "$dir/j.json"
"$FRINGE" estimate "$dir/jump.csv" --estimator ekf-auto --report "$dir/ja.json" > "$dir/ja.txt"
grep -q "^ekf-auto: the signal changed 1 time" "$dir/ja.txt" || fail "no signal-change line: $(cat "$dir/ja.txt")"
# and says nothing of the kind on the clean capture; without -o or --report the summary is the output
"$FRINGE" estimate "$dir/cap.csv" --estimator ekf-diffraction > "$dir/c.txt"
grep -q "^error after 0.1 s settle" "$dir/c.txt" || fail "summary-only: $(cat "$dir/c.txt")"
! grep -q "loss of lock\|not taken in" "$dir/c.txt" || fail "clean capture: $(cat "$dir/c.txt")"
grep -q "^warning: only 25 % of the 20000 samples after the settle time are valid" "$dir/j.txt" || fail "no low-valid warning: $(cat "$dir/j.txt")"
grep -q "^warning: ekf-auto learns the waveform shape .* covers 10.7 electrical cycles" "$dir/ja.txt" || fail "no scores_learning warning: $(cat "$dir/ja.txt")"
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); c=[w["code"] for w in r["warnings"]]; assert "scores_learning" in c, c; f=[(x["metric"],x["outcome"]) for x in r["measurements"]]; assert ("valid_fraction","FAIL") in f, f; e=r["capture"]["estimates"]; assert e["samples"]==30000 and 0<e["valid_fraction"]<1, e' "$dir/ja.json"
! grep -q "^warning" "$dir/c.txt" || fail "clean capture warned: $(cat "$dir/c.txt")"

# truth, but nothing scored: exit 1, not success
set +e; "$FRINGE" estimate "$dir/cap.csv" --estimator atan2 --settle-s 5 > "$dir/ns.txt"; rc=$?; set -e
[ $rc -eq 1 ] && grep -q "^no scored samples" "$dir/ns.txt" || fail "nothing scored: exit $rc: $(cat "$dir/ns.txt")"
# without truth the summary still says how much the estimator vouched for
"$FRINGE" estimate "$dir/notruth.csv" --estimator ekf-auto > "$dir/nt.txt"
grep -q "estimates only; valid [0-9.]* % of 30000 samples" "$dir/nt.txt" || fail "no-truth valid fraction: $(cat "$dir/nt.txt")"

# an output never overwrites an input (the capture, its sidecar, the scenario) or the other output
cp "$dir/cap.csv" "$dir/keep.csv"; cp "$dir/cap.json" "$dir/keep.json"; ln -s keep.csv "$dir/link.csv"
expect_error "keep.csv is the capture: writing it would destroy it" "$FRINGE" estimate "$dir/keep.csv" --estimator atan2 -o "$dir/keep.csv"
expect_error "link.csv is the capture" "$FRINGE" estimate "$dir/keep.csv" --estimator atan2 -o "$dir/link.csv"
expect_error "keep.json is the capture's sidecar" "$FRINGE" estimate "$dir/keep.csv" --estimator atan2 --report "$dir/keep.json"
expect_error "is also the output" "$FRINGE" estimate "$dir/keep.csv" --estimator atan2 -o "$dir/o.x" --report "$dir/./o.x"
cmp -s "$dir/cap.csv" "$dir/keep.csv" && cmp -s "$dir/cap.json" "$dir/keep.json" || fail "an input was overwritten"
# where a sidecar would be read from, even before one exists; and a report found there is not metadata
expect_error "notruth.json is the capture's sidecar" "$FRINGE" estimate "$dir/notruth.csv" --estimator atan2 --report "$dir/notruth.json"
[ ! -e "$dir/notruth.json" ] || fail "the report was written where the sidecar goes"
cp "$dir/r.json" "$dir/keep.json"
expect_error "keep.json: sidecar is a fringe.report report, not a capture's metadata" "$FRINGE" estimate "$dir/keep.csv" --estimator atan2
cp "$SRC/fixtures/scenarios/paper-duty1p6.json" "$dir/scen.json"
expect_error "output's sidecar: .*scen.json is the scenario" "$FRINGE" gen "$dir/scen.json" -o "$dir/scen.csv" -q --samples 100
expect_error "report: .*scen.json is the scenario" "$FRINGE" run "$dir/scen.json" --report "$dir/scen.json" --data "$dir/data"
# a CSV recording writes x.json beside x.csv: over the scenario, or over the report (a new user's trial lost both)
expect_error "record (its sidecar): .*scen.json is the scenario" "$FRINGE" run "$dir/scen.json" --record "$dir/scen.csv" --no-db
expect_error "record (its sidecar): .*o.json is also the report" "$FRINGE" run "$dir/scen.json" --report "$dir/o.json" --record "$dir/o.csv" --no-db
[ ! -e "$dir/o.json" ] && [ ! -e "$dir/o.csv" ] || fail "run wrote before refusing"
# a device or FIFO as a JSON file: refused at once, not read forever
expect_error "is not a regular file" "$FRINGE" run /dev/zero --no-db
mkfifo "$dir/fifo.json"
expect_error "fifo.json' is not a regular file" timeout 10 "$FRINGE" run "$dir/fifo.json" --no-db
cmp -s "$SRC/fixtures/scenarios/paper-duty1p6.json" "$dir/scen.json" || fail "the scenario was overwritten"
[ ! -e "$dir/scen.csv" ] || fail "gen wrote its capture before refusing"
# numbers on the command line are finite
expect_error "settle-s: 'nan' is not a finite number" "$FRINGE" estimate "$dir/cap.csv" --estimator atan2 --settle-s nan
expect_error "settle-s: 'inf' is not a finite number" "$FRINGE" estimate "$dir/cap.csv" --estimator atan2 --settle-s inf
expect_error "max-upload-mb: 'nan' is not a finite number" "$FRINGE" serve --max-upload-mb nan --data "$dir/data"
echo "cli.estimate OK"
