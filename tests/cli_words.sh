#!/usr/bin/env bash
# The words fringe prints, through the real executable: each message names what is wrong in the
# terms the user typed (the key they gave, the speed in rpm, the limit a test was held to).
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
ok() { echo "ok - $*"; }
S="$SRC/fixtures/scenarios"

# A scenario from the fig10c fixture with one change (a Python expression on the dict s).
scenario() {
  $PY - "$S/fig10c-loopback.json" "$1" "$2" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["encoder"] = sys.argv[1].rsplit("/", 2)[0] + "/encoders/paper-d2-analog.json"
s["duration_s"] = 0.3
exec(sys.argv[3])
json.dump(s, open(sys.argv[2], "w"))
PY
}

# An unknown estimator is reported at the key the user wrote: estimators[i].name.
scenario "$dir/est.json" 's["estimators"][1]["name"] = "atan3"'
set +e; msg=$("$FRINGE" run "$dir/est.json" --no-db -q 2>&1); rc=$?; set -e
[ $rc -eq 2 ] && grep -q "estimators\[1\]\.name: unknown estimator 'atan3'" <<<"$msg" || fail "unknown estimator: exit $rc, $msg"
grep -q "estimators\[1\]\.estimator" <<<"$msg" && fail "still reported at .estimator: $msg"
ok "unknown estimator named at estimators[1].name"

# "speed_rpm" in a motion: the unknown key is named with the keys a constant motion takes.
scenario "$dir/rpm.json" 's["motion"] = {"kind": "constant", "speed_rpm": 600}'
set +e; msg=$("$FRINGE" run "$dir/rpm.json" --no-db -q 2>&1); rc=$?; set -e
[ $rc -eq 2 ] || fail "speed_rpm: exit $rc"
for want in "motion.speed_rpm: unknown key" "velocity_rad_s" "electrical_freq_hz" "600 rpm is 62.83 rad/s"; do
  grep -qF "$want" <<<"$msg" || fail "speed_rpm message lacks '$want': $msg"
done
grep -q "required key is missing" <<<"$msg" && fail "speed_rpm still says a key is missing: $msg"
ok "speed_rpm: $(echo "$msg" | head -1 | cut -c1-150)"

# 600 rad/s typed for 600 rpm on 1024 lines at 100 kHz: undersampled, and the speed in rpm shown.
scenario "$dir/fast.json" 's["motion"] = {"kind": "constant", "velocity_rad_s": 600}'
set +e; msg=$("$FRINGE" run "$dir/fast.json" --no-db -q 2>&1); rc=$?; set -e
[ $rc -eq 2 ] && grep -q "undersampled" <<<"$msg" || fail "600 rad/s: exit $rc, $msg"
grep -qE "600 rad/s = 5730 rpm" <<<"$msg" || fail "undersampling message without the speed in rpm: $msg"
ok "undersampled at 600 rad/s = 5730 rpm"

# JUnit failure messages carry the limit; the offline HTML prints no literal null (atan2-ellipse
# never fits within the run, so it has no scored samples and no slip count).
scenario "$dir/failing.json" 's["limits"] = [{"estimator": "atan2", "metric": "rms_rad", "max": 1e-9, "marginal_fraction": 0.2}]; s["estimators"].append({"name": "atan2-ellipse", "params": {"calibration_samples": 100000000}})'
set +e; "$FRINGE" run "$dir/failing.json" --no-db -q --junit "$dir/f.xml" --html "$dir/f.html" --report "$dir/f.json"; rc=$?; set -e
[ $rc -eq 1 ] || fail "failing run: exit $rc"
$PY - "$dir" <<'PY'
import json, sys, re, xml.etree.ElementTree as ET
d = sys.argv[1]
r = json.load(open(d + "/f.json"))
unscored = [e for e in r["estimators"] if e["label"] == "atan2-ellipse"][0]["metrics"]
assert unscored.get("slipped_samples") is None, unscored.get("slipped_samples")
fails = [f.get("message") for f in ET.parse(d + "/f.xml").getroot().iter("failure")]
rms = [m for m in fails if m.startswith("atan2 rms_rad = ")]
assert len(rms) == 1 and "limit <= 1e-09 rad (marginal within 20 %)" in rms[0], fails
assert all(", limit " in m for m in fails), fails
html = open(d + "/f.html").read()
cells = re.findall(r"<td[^>]*>([^<]*)</td>", html)
assert "null" not in cells, "offline HTML prints null"
est = html[html.index('<table id="estimators">'):]
row = re.search(r"<tr><td>atan2-ellipse</td>.*?</tr>", est).group(0)
slips = re.search(r'<td class="num m-slipped_samples"[^>]*>([^<]*)</td>', row).group(1)
assert slips == "not measured", row
print("ok - JUnit failure message:", rms[0])
print("ok - offline HTML: an unscored estimator's slips read 'not measured'")
PY

# gen: a duty-cycle error that rounds to zero prints 0.00, not -0.00.
# (the ideal encoder, 0.5 s, seed 3: an error of a few 1e-3 % that printed with a sign)
scenario "$dir/ideal.json" 's["encoder"] = s["encoder"].replace("paper-d2-analog", "ideal"); s["duration_s"] = 0.5; s["seed"] = 3'
"$FRINGE" gen "$dir/ideal.json" -o "$dir/g.csv" > "$dir/gen.txt" 2>&1 || fail "gen: $(cat "$dir/gen.txt")"
grep -q "duty-cycle error" "$dir/gen.txt" || fail "gen prints no duty-cycle line: $(cat "$dir/gen.txt")"
grep -q "duty-cycle error 0.00 %" "$dir/gen.txt" || fail "gen: expected 0.00: $(grep duty "$dir/gen.txt")"
ok "gen: $(grep -o 'duty-cycle error [^,]*' "$dir/gen.txt")"

# estimate --estimator atan2-ellipse on a capture without truth: the warning says why its
# samples are invalid on the same line (it pointed at notes that never followed).
$PY - "$dir/c.csv" <<'PY'
import math, sys
with open(sys.argv[1], "w") as f:
    f.write("t,sin,cos\n")
    for i in range(30000):
        th = 2 * math.pi * 200 * i / 1e5
        f.write(f"{i/1e5},{0.8*math.sin(th)},{0.7*math.cos(th)+0.01}\n")
PY
printf '{"sample_rate_hz": 100000}\n' > "$dir/c.json"
out=$("$FRINGE" estimate "$dir/c.csv" --estimator atan2-ellipse 2>&1) || fail "estimate: $out"
grep -q "read its notes below" <<<"$out" && fail "estimate still points at notes that do not follow: $out"
grep -q "warning: atan2-ellipse marked .* of the samples invalid: ellipse fit ok" <<<"$out" || fail "estimate's warning names no reason: $out"
ok "estimate: $(echo "$out" | grep warning | cut -c1-160)"
echo "PASS"
