#!/usr/bin/env bash
# Calibrate, apply, re-run in one `fringe run` (docs/calibration.md "In one run"), through the
# real executable: the fixture's before and after passes in one report, the summary's table, the
# correction written beside the report, the HTML section, and refusals before anything runs.
set -euo pipefail
FRINGE="$1"; SRC="$2"
PY=/usr/bin/python3
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
ok() { echo "ok - $*"; }

set +e
out=$("$FRINGE" run "$SRC/fixtures/scenarios/paper-duty1p6-calibrate.json" --no-db --report "$dir/r.json" --html "$dir/r.html" --junit "$dir/r.xml" 2>&1)
rc=$?
set -e
echo "$out"
[ "$rc" -eq 0 ] || fail "exit $rc (the after pass's limit should pass)"
for want in "calibration of atan2: verified" "computed on the before pass (seed 1" "truth-scored error" "verified on the after pass (seed 2" \
            "rms before" "after/CRB" "applied (estimator_param)" "limits: the verdict and measurements are the after pass's"; do
  grep -qF "$want" <<<"$out" || fail "summary lacks '$want'"
done
$PY - "$dir/r.json" "$dir" <<'PY' || fail "the report's calibration"
import json, sys, os, hashlib
r = json.load(open(sys.argv[1]))
c = r["calibration"]
assert r["schema"] == "fringe.report" and r["verdict"] == "PASS", r["verdict"]
assert c["status"] == "verified"
assert c["computed_on"]["seed"] == 1 and c["verified_on"]["seed"] == 2 and r["seed"] == 2
path = c["correction"]["path"]
assert os.path.dirname(path) == os.path.realpath(sys.argv[2]) or os.path.dirname(path) == sys.argv[2], path
assert hashlib.sha256(open(path, "rb").read()).hexdigest() == c["correction"]["sha256"]
lanes = {l["label"]: l for l in c["lanes"]}
a = lanes["atan2"]
b, af, crb = a["before"]["rms_rad"], a["after"]["rms_rad"], a["after"]["per_sample_crb_rad"]
print(f"atan2 rms before {b:.4g} after {af:.4g} rad, CRB {crb:.4g}, after/CRB {af/crb:.3g}, predicted {a['predicted_rms_rad']:.4g}")
p = lanes["pll2"]
print(f"pll2 rms before {p['before']['rms_rad']:.4g} after {p['after']['rms_rad']:.4g} rad")
assert abs(b - 1.78e-2) < 0.02 * 1.78e-2, b
assert af < 2 * crb, (af, crb)
assert p["after"]["rms_rad"] < p["before"]["rms_rad"] / 20
assert c["before"]["estimators"][0]["metrics"]["rms"]["rad"] == b
# no capture left behind: only the report, the HTML and the correction
assert sorted(os.listdir(sys.argv[2])) == sorted(["r.json", "r.html", "r.xml", os.path.basename(path)]), os.listdir(sys.argv[2])
PY
ok "before and after in one report, the correction beside it"
grep -q '<table id="calibration-lanes">' "$dir/r.html" || fail "the HTML has no before/after table"
grep -q 'id="calibration-status" class="PASS">verified' "$dir/r.html" || fail "the HTML does not say verified"
ok "the HTML report's calibration section"
grep -q '<property name="calibration.status" value="verified"/>' "$dir/r.xml" || fail "JUnit: no calibration.status"
grep -qE '<property name="calibration.atan2.rms_after_rad" value="0\.000[0-9]+ \(truth\)"/>' "$dir/r.xml" || fail "JUnit: no atan2 rms after"
grep -q '<property name="calibration.verified_on" value="seed 2, device loopback:"/>' "$dir/r.xml" || fail "JUnit: no verified_on"
ok "JUnit's calibration properties"

# Refused with the scenario: exit 2, nothing run.
$PY - "$SRC" "$dir" <<'PY'
import json, sys
src, d = sys.argv[1], sys.argv[2]
s = json.load(open(f"{src}/fixtures/scenarios/paper-duty1p6-calibrate.json"))
s["encoder"] = f"{src}/fixtures/encoders/paper-d2-duty1p6.json"
s["estimators"].append({"name": "ekf-ideal", "label": "ekf"})
for name, cal in [("nolane", {"lane": "atan3"}), ("ekf", {"lane": "ekf"}), ("typo", {"lane": "atan2", "verfy": {"seed": 2}}),
                  ("same", {"lane": "atan2", "verify": {"seed": 1}})]:
    s["calibrate"] = cal
    json.dump(s, open(f"{d}/{name}.json", "w"))
PY
check_refused() {
  set +e
  msg=$("$FRINGE" run "$dir/$1.json" --no-db -q 2>&1)
  rc=$?
  set -e
  [ "$rc" -eq 2 ] || fail "$1: exit $rc"
  grep -qF "$2" <<<"$msg" || fail "$1: '$msg' lacks '$2'"
  ok "$1 refused: $2"
}
check_refused nolane "no estimator labelled 'atan3' in this scenario (its lanes: 'atan2', 'pll2', 'ekf')"
check_refused ekf "a correction can only be computed for atan2"
check_refused typo "did you mean 'verify'"
check_refused same "same capture as the before pass"

# Too short for a correction: no verdict from the before pass, the reason, exit 2.
$PY - "$SRC" "$dir" <<'PY'
import json, sys
src, d = sys.argv[1], sys.argv[2]
s = json.load(open(f"{src}/fixtures/scenarios/paper-duty1p6-calibrate.json"))
s["encoder"] = f"{src}/fixtures/encoders/paper-d2-duty1p6.json"
s["duration_s"] = 0.108
json.dump(s, open(f"{d}/short.json", "w"))
PY
set +e
out=$("$FRINGE" run "$dir/short.json" --no-db --report "$dir/short-report.json" 2>&1)
rc=$?
set -e
[ "$rc" -eq 2 ] || fail "short: exit $rc"
grep -qF "calibration of atan2: no_correction" <<<"$out" || fail "short: $out"
grep -qF "too few electrical cycles for a correction" <<<"$out" || fail "short: no reason"
ok "too few cycles: no correction, exit 2"

# --record over a capture the run reads (found by a hostile trial): the replayed capture was
# truncated, and the verify capture replaced by the before pass's samples and "verified" on them.
"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/ca.fcap" -q --seed 11
"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/cb.fcap" -q --seed 12
$PY - "$SRC" "$dir" <<'PY'
import json, sys
src, d = sys.argv[1], sys.argv[2]
json.dump({"name": "replay", "device": f"capture:{d}/ca.fcap", "encoder": f"{src}/fixtures/encoders/paper-d2-duty1p6.json",
           "estimators": [{"name": "atan2"}], "calibrate": {"lane": "atan2", "verify": {"device": f"capture:{d}/cb.fcap"}}},
          open(f"{d}/replay.json", "w"))
PY
cp "$dir/ca.fcap" "$dir/ca.orig"; cp "$dir/cb.fcap" "$dir/cb.orig"
for target in ca.fcap cb.fcap; do
  set +e; msg=$("$FRINGE" run "$dir/replay.json" --no-db -q --record "$dir/$target" 2>&1); rc=$?; set -e
  [ $rc -eq 2 ] && grep -q "is the capture" <<<"$msg" || fail "--record $target: exit $rc, $msg"
done
cmp -s "$dir/ca.fcap" "$dir/ca.orig" && cmp -s "$dir/cb.fcap" "$dir/cb.orig" || fail "a capture the run reads was changed"
ok "--record over a capture the run reads is refused before anything runs"
