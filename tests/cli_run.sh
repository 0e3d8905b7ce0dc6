#!/usr/bin/env bash
# fringe run / fringe runs through the real executable: exit codes, the three report formats,
# the history, and a kill -9 during a run losing no completed report.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
dir=$(mktemp -d); trap 'kill -9 $pid 2>/dev/null || true; rm -rf "$dir"' EXIT
pid=
fail() { echo "FAIL: $*" >&2; exit 1; }
S="$SRC/fixtures/scenarios"

"$FRINGE" run "$S/fig10c-loopback.json" --data "$dir/data" --report "$dir/r.json" --junit "$dir/r.xml" --html "$dir/r.html" -q \
  || fail "fig10c-loopback should pass"
$PY - "$dir" <<'PY'
import json, sys, xml.etree.ElementTree as ET
d = sys.argv[1]
r = json.load(open(d + "/r.json"))
assert r["schema"] == "fringe.report" and r["verdict"] == "PASS", r["verdict"]
suite = ET.parse(d + "/r.xml").getroot().find("testsuite")
cases = suite.findall("testcase")
# 4 limits, and the 5 evidence checks of each of the 3 estimators first
assert r["schema_version"] == 3
assert len(cases) == len(r["measurements"]) == 19, len(cases)  # five evidence checks for each of three estimators, and four limits
props = {p.get("name"): p.get("value") for p in cases[0].find("properties")}
assert props["unit"] == "samples" and props["evidence"] == "true" and props["outcome"] == "PASS", props
props = {p.get("name"): p.get("value") for p in cases[15].find("properties")}
assert props["unit"] == "rad" and "max" in props and props["outcome"] == "PASS", props
html = open(d + "/r.html").read()
assert html.count("<svg") >= 4 and "PASS" in html
# Issue 11: the Lissajous joins only neighbouring bins of the folded cycle; the spectrum is there.
import math, re
def svg(i):
    m = re.search(r'<svg id="%s".*?</svg>' % i, html)
    assert m, i + " missing"
    return m.group(0)
segs = []
for pts in re.findall(r'<polyline[^>]*points="([^"]*)"', svg("plot-lissajous")):
    p = [tuple(map(float, q.split(","))) for q in pts.split()]
    segs += [math.dist(a, b) for a, b in zip(p, p[1:])]
assert len(segs) >= 200 and max(segs) < 8, (len(segs), max(segs, default=0))
assert "<polyline" in svg("plot-spectrum") and "amplitude (rad)" in svg("plot-spectrum")
assert all(e["spectrum"]["segments"] > 0 for e in r["estimators"])
PY

set +e
# A report to a FIFO (or /dev/null) is written into it, never replaced by a file renamed over
# it: as root, `--report /dev/null` once turned /dev/null into a regular file.
mkfifo "$dir/r.fifo"
timeout 60 cat "$dir/r.fifo" > "$dir/from-fifo.json" & catpid=$!
timeout 120 "$FRINGE" run "$S/fig10c-loopback.json" --no-db --report "$dir/r.fifo" -q || fail "a run reporting into a FIFO should pass"
wait $catpid || fail "the FIFO's reader got no end of file (the report did not go into the FIFO)"
[ -p "$dir/r.fifo" ] || fail "the FIFO was replaced by a file"
$PY -c 'import json,sys; assert json.load(open(sys.argv[1]))["schema"] == "fringe.report"' "$dir/from-fifo.json" || fail "the FIFO's reader did not get the report"

"$FRINGE" run "$S/ci-failing.json" --data "$dir/data" --junit "$dir/f.xml" -q; rc=$?
set -e
[ $rc -eq 1 ] || fail "ci-failing: exit $rc, want 1"
$PY -c 'import sys, xml.etree.ElementTree as ET; s=ET.parse(sys.argv[1]).getroot().find("testsuite"); assert s.get("failures")=="1"' "$dir/f.xml"

# sample loss is never silent: ERROR, exit 2, with the count
$PY - "$S/fig10c-loopback.json" "$dir/loss.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); s["device"] = "loopback:?drop_after=5000&drop_count=3"; s["duration_s"] = 0.2; s["name"] = "loss-run"
s["encoder"] = sys.argv[1].rsplit("/", 1)[0] + "/" + s["encoder"]
json.dump(s, open(sys.argv[2], "w"))
PY
set +e
out=$("$FRINGE" run "$dir/loss.json" --data "$dir/data" --report "$dir/loss-r.json" 2>&1); rc=$?
set -e
[ $rc -eq 2 ] || fail "sample loss: exit $rc, want 2"
grep -q "sample loss: 3 input samples dropped" <<<"$out" || fail "loss message: $out"

# bad scenario: exit 2 naming the key
$PY -c 'import json,sys; s=json.load(open(sys.argv[1])); s["limits"][0]["metric"]="rms"; s["encoder"]=sys.argv[1].rsplit("/",1)[0]+"/"+s["encoder"]; json.dump(s,open(sys.argv[2],"w"))' \
  "$S/fig10c-loopback.json" "$dir/bad.json"
set +e
out=$("$FRINGE" run "$dir/bad.json" --data "$dir/data" 2>&1); rc=$?
set -e
[ $rc -eq 2 ] || fail "bad scenario: exit $rc"
grep -q "limits\[0\].metric" <<<"$out" || fail "bad scenario message: $out"

# kill -9 during a long run: completed reports survive, the killed run shows as interrupted
$PY -c 'import json,sys; s=json.load(open(sys.argv[1])); s["duration_s"]=600; s["name"]="long-run"; s["encoder"]=sys.argv[1].rsplit("/",1)[0]+"/"+s["encoder"]; json.dump(s,open(sys.argv[2],"w"))' \
  "$S/fig10c-loopback.json" "$dir/long.json"
"$FRINGE" run "$dir/long.json" --data "$dir/data" -q & pid=$!
sleep 1.5
kill -9 $pid; wait $pid 2>/dev/null || true
"$FRINGE" runs --data "$dir/data" --json > "$dir/runs.json"
$PY - "$dir/runs.json" <<'PY'
import json, sys
rows = json.load(open(sys.argv[1]))
by = {r["scenario"]: r for r in rows}
assert by["fig10c-loopback"]["verdict"] == "PASS", rows
assert by["ci-failing"]["verdict"] == "FAIL", rows
assert by["long-run"]["status"] == "interrupted", rows
assert by["loss-run"]["verdict"] == "ERROR", rows
PY
id=$($PY -c 'import json,sys; print([r for r in json.load(open(sys.argv[1])) if r["scenario"]=="fig10c-loopback"][0]["id"])' "$dir/runs.json")
"$FRINGE" runs --data "$dir/data" --show "$id" --json | $PY -c 'import json,sys; assert json.load(sys.stdin)["verdict"]=="PASS"'
# --show without --json: the summary a person reads (verdict, limits beside values), not 100s of KB of JSON
"$FRINGE" runs --data "$dir/data" --show "$id" > "$dir/show.txt"
grep -q "PASS (done)" "$dir/show.txt" && grep -q "(limit <= " "$dir/show.txt" || fail "runs --show summary: $(head -5 "$dir/show.txt")"
[ "$(wc -c < "$dir/show.txt")" -lt 20000 ] || fail "runs --show prints a summary, not the report"
"$FRINGE" runs --data "$dir/data" --verdict FAIL | grep -q ci-failing || fail "runs --verdict"
# filters: case-insensitive verdicts; bad values are errors naming the option, not an empty list
"$FRINGE" runs --data "$dir/data" --verdict fail | grep -q ci-failing || fail "runs --verdict fail (lower case)"
set +e; "$FRINGE" runs --data "$dir/data" --verdict BOGUS > /dev/null 2> "$dir/err.txt"; rc=$?; set -e
[ $rc -eq 2 ] && grep -q "verdict" "$dir/err.txt" || fail "runs --verdict BOGUS: exit $rc, $(cat "$dir/err.txt")"
set +e; "$FRINGE" runs --data "$dir/data" --since someday > /dev/null 2> "$dir/err.txt"; rc=$?; set -e
[ $rc -eq 2 ] && grep -q "since" "$dir/err.txt" || fail "runs --since someday: exit $rc"
"$FRINGE" runs --data "$dir/data" --since yesterday | grep -q ci-failing || fail "runs --since yesterday"
"$FRINGE" runs --data "$dir/data" --since 2999-01-01 2>/dev/null | grep -q ci-failing && fail "runs --since in the future lists nothing"
# a misspelt key: did you mean, and the file named
$PY -c 'import json,sys; s=json.load(open(sys.argv[1])); s["setle_s"]=s.pop("settle_s"); s["encoder"]=sys.argv[1].rsplit("/",1)[0]+"/"+s["encoder"]; json.dump(s,open(sys.argv[2],"w"))' \
  "$SRC/fixtures/scenarios/fig10c-loopback.json" "$dir/typo.json"
set +e; "$FRINGE" run "$dir/typo.json" --no-db > /dev/null 2> "$dir/err.txt"; rc=$?; set -e
[ $rc -eq 2 ] && grep -q "setle_s: unknown key (did you mean 'settle_s'?) (in $dir/typo.json)" "$dir/err.txt" || fail "typo: exit $rc, $(cat "$dir/err.txt")"
# --record: the device input with aligned truth; re-estimating it gives the run's figure exactly
"$FRINGE" run "$S/agc-drift.json" --no-db --record "$dir/rec.fcap" --report "$dir/agc.json" -q
"$FRINGE" estimate "$dir/rec.fcap" --estimator ekf-diffraction --param agc=true --param q_gain_per_s=0.01 --report "$dir/re.json" -q
$PY -c 'import json,sys; a=json.load(open(sys.argv[1])); b=json.load(open(sys.argv[2])); x=[e for e in a["estimators"] if e["label"]=="agc"][0]["metrics"]["rms"]["rad"]; y=b["estimators"][0]["metrics"]["rms"]["rad"]; assert x==y, (x,y)' "$dir/agc.json" "$dir/re.json"

# SIGINT: the run ends ABORTED (exit 2) and its report is kept
"$FRINGE" run "$dir/long.json" --data "$dir/data" --report "$dir/int.json" -q & pid=$!
sleep 1.5
kill -INT $pid
set +e; wait $pid; rc=$?; set -e
[ $rc -eq 2 ] || fail "interrupted run: exit $rc"
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); assert r["verdict"]=="ABORTED" and r["status"]=="aborted", r["verdict"]' "$dir/int.json"
"$FRINGE" runs --data "$dir/data" --verdict ABORTED | grep -q long-run || fail "aborted run not in history"
echo "cli.run OK"
