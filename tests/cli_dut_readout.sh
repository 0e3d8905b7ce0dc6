#!/usr/bin/env bash
# The live bench's DUT lane end to end (issue 29, docs/dut-readouts.md "In a run"), all on
# 127.0.0.1: fixtures/scenarios/scpi-awg-digitizer.json on `fringe instrument-sim --bench` (a
# generator plays the motion, a digitizer records it) with a third device, the DUT's own
# position stream over TCP (tests/dut_stream.py: a DUT 80 us late, some words flagged E, some
# lines garbled). One `fringe run` scores the DUT against truth with its latency measured and
# its wire errors counted; a DUT later than a limit FAILs (exit 1); a stream cut mid-run is
# an ERROR naming device.dut (exit 2) with the estimators' figures kept. A live logic analyser
# through sigrok-cli (its demo driver, whose D0/D1 pattern is no quadrature) reads as the DUT:
# every sample acquired and decoded, the illegal transitions counted, and a FAIL for want of
# evidence, never a PASS.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pids=()
trap 'for p in "${pids[@]}"; do kill $p 2>/dev/null || true; done; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; for f in "$dir"/*.log; do echo "== $f" >&2; cat "$f" >&2; done; exit 1; }
F="$SRC/fixtures/scenarios/scpi-awg-digitizer.json"

"$FRINGE" instrument-sim --port 0 --exit-after 100 --bench > "$dir/isim.log" 2>&1 &
pids+=($!)
GEN=$(poll_log "$dir/isim.log" 's/^instrument-sim generator \(scpi[^?]*\).*/\1/p') || fail "instrument-sim did not start"
DIG=$(poll_log "$dir/isim.log" 's/^instrument-sim digitizer \(scpi[^?]*\).*/\1/p') || fail "instrument-sim did not start"

dut() {  # dut NAME ARGS...: serve a DUT stream, set DUT_PORT
  local name=$1; shift
  $PY "$SRC/tests/dut_stream.py" 1234.5 "$@" --serve > "$dir/$name-dut.log" 2>&1 &
  pids+=($!)
  DUT_PORT=$(poll_log "$dir/$name-dut.log" 's/^port \([0-9]*\)$/\1/p') || fail "the DUT stream $name did not start"
}
scenario() {  # scenario OUT DUT_QUERY [JQ]
  jq --arg g "$GEN?model=keysight-33500b" --arg d "$DIG?model=generic-scope&pretrigger_samples=256" \
     --arg u "readout:tcp://127.0.0.1:$DUT_PORT?$2" ".device.output=\$g | .device.input=\$d | .device.dut=\$u ${3:-}" "$F" > "$1"
}

# 1. The DUT scored live beside the estimators: latency and wire errors in the report.
dut ok 80e-6 4096 20000 0.5 --flag-every 50 --garbage-every 100
scenario "$dir/ok.json" "counts_per_rev=4096" '| .limits += [{"estimator": "dut", "metric": "dut_latency_s", "max": 1e-4}]'
"$FRINGE" run "$dir/ok.json" --no-db --report "$dir/ok-report.json" > "$dir/ok-run.log" 2>&1 || fail "the bench with a DUT 80 us late should PASS its limits"
$PY - "$dir/ok-report.json" <<'PY' || fail "the DUT lane's report"
import json, math, sys
r = json.load(open(sys.argv[1]))
assert r["verdict"] == "PASS", r["verdict"]
dut = [e for e in r["estimators"] if e["label"] == "dut"][0]
m, ro = dut["metrics"], dut["metrics"]["readout"]
# 20 kHz words over 0.5 s: every 50th flagged, a garbled line before every 100th.
assert ro["words_received"] >= 9990, ro
assert ro["error_flags"] == 200, ro["error_flags"]
assert ro["malformed_lines"] == 100, ro["malformed_lines"]
assert abs(ro["latency_s"] - 80e-6) < 0.02 * 80e-6, ro["latency_s"]
omega = 2 * math.pi * 1234.5
assert abs(m["mean"]["rad"] + omega * 80e-6) < 0.01 * omega * 80e-6, m["mean"]
assert m["slipped_samples"] == 0
codes = [w["code"] for w in r["warnings"]]
assert "dut_wire_errors" in codes, codes
wire = [x for x in r["measurements"] if x["metric"] == "dut_latency_s"][0]
assert wire["outcome"] == "PASS", wire
print("dut lane ok: latency", ro["latency_s"], "wire errors", ro["error_flags"] + ro["malformed_lines"])
PY
grep -q "dut " "$dir/ok-run.log" || fail "the CLI summary should show the dut lane"

# 2. A DUT later than its limit: FAIL, exit 1.
dut late 150e-6 4096 20000 0.5
scenario "$dir/late.json" "counts_per_rev=4096" '| .limits += [{"estimator": "dut", "metric": "dut_latency_s", "max": 1e-4}]'
set +e
"$FRINGE" run "$dir/late.json" --no-db -q --report "$dir/late-report.json" > "$dir/late-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 1 ] || fail "a DUT 150 us late against a 100 us limit should exit 1, got $rc"
jq -e '[.measurements[] | select(.metric == "dut_latency_s" and .outcome == "FAIL")] | length == 1' "$dir/late-report.json" > /dev/null || fail "the latency limit should FAIL"

# 3. The DUT's stream cut mid-run: ERROR naming device.dut, exit 2, the estimators kept.
dut cut 0 4096 20000 0.5 --cut 0.5
scenario "$dir/cut.json" "counts_per_rev=4096"
set +e
"$FRINGE" run "$dir/cut.json" --no-db -q --report "$dir/cut-report.json" > "$dir/cut-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 2 ] || fail "a DUT stream cut mid-run should exit 2, got $rc"
jq -e '.status == "error" and (.error | contains("device.dut"))' "$dir/cut-report.json" > /dev/null || fail "the error should name device.dut"
jq -e '[.estimators[] | select(.label == "atan2") | .metrics.evidence.scored_samples] | .[0] > 10000' "$dir/cut-report.json" > /dev/null ||
  fail "the estimators' figures should survive the DUT's fault"
# 4. Live: sigrok's demo logic analyser as the DUT's ABZ lines (the simulated chain for the signals).
#    Without a Z line an ABZ readout is refused (its absolute position would be unknown).
jq '.device = {"output": "loopback:", "input": "loopback:", "dut": "readout:sigrok://demo?protocol=abz&a=D0&b=D1&interpolation=4&word_rate_hz=10000&logic_rate_hz=1000000"}
    | .limits = [] | .duration_s = 0.3 | .settle_s = 0.05' "$F" > "$dir/noz.json"
set +e
timeout 60 "$FRINGE" run "$dir/noz.json" --no-db -q > "$dir/noz-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 2 ] && grep -q "needs its index line Z" "$dir/noz-run.log" || fail "an ABZ readout without Z should be refused naming Z (exit $rc)"
jq '.device.dut |= sub("&b=D1"; "&b=D1&z=D2")' "$dir/noz.json" > "$dir/live.json"
set +e
timeout 120 "$FRINGE" run "$dir/live.json" --no-db -q --report "$dir/live-report.json" > "$dir/live-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 1 ] || fail "a DUT whose lines are the demo's pattern should FAIL (exit 1), got $rc"
$PY - "$dir/live-report.json" <<'PY' || fail "the live readout's report"
import json, sys
r = json.load(open(sys.argv[1]))
assert r["status"] == "done", r.get("error")
ro = [e for e in r["estimators"] if e["label"] == "dut"][0]["metrics"]["readout"]
sg = ro["sigrok"]
# Acquired live for the run's 0.3 s at 1 MHz (and a little more), every sample decoded.
assert sg["samples"] >= 300000 and ro["logic_samples"] == sg["samples"], (sg["samples"], ro["logic_samples"])
assert sg["logic_channels"] == ["D0", "D1", "D2"], sg["logic_channels"]
assert ro["abz"]["illegal_transitions"] > 0, ro["abz"]
assert ro["words_received"] >= 2900, ro["words_received"]
assert r["verdict"] == "FAIL"
print("live demo readout ok:", sg["samples"], "samples,", ro["abz"]["illegal_transitions"], "illegal transitions")
PY

# 5. The whole bench in one run: the emulated generator plays the motion, the emulated digitizer
#    records it, and an ABZ board's answer recorded by a logic analyser (tests/abz_sr.py: 60 us
#    late, N = 16, five glitches where A and B both flip, two index pulses lost) streams in
#    through the live sigrok path
#    (sigrok-cli -i: the path of readout:sigrok://DRIVER, replaying the analyser's session).
$PY "$SRC/tests/abz_sr.py" 1234.5 60e-6 16 2000000 0.52 "$dir/board.sr" --glitches 5 --drop-index 2 > "$dir/abz-sr.log" 2>&1 || fail "tests/abz_sr.py"
DUT_PORT=0
scenario "$dir/bench.json" "" '| .limits += [{"estimator": "dut", "metric": "dut_latency_s", "max": 1e-4}, {"estimator": "dut", "metric": "dut_wire_errors", "max": 20}]'
jq --arg u "readout:sigrok://$dir/board.sr?protocol=abz&a=A&b=B&z=Z&interpolation=16&word_rate_hz=20000" '.device.dut = $u' "$dir/bench.json" > "$dir/bench2.json"
timeout 300 "$FRINGE" run "$dir/bench2.json" --no-db --report "$dir/bench-report.json" > "$dir/bench-run.log" 2>&1 || fail "the whole bench with a replayed ABZ board should PASS"
$PY - "$dir/bench-report.json" <<'PY' || fail "the whole bench's report"
import json, math, sys
r = json.load(open(sys.argv[1]))
assert r["verdict"] == "PASS", r["verdict"]
dut = [e for e in r["estimators"] if e["label"] == "dut"][0]
m, ro = dut["metrics"], dut["metrics"]["readout"]
sg = ro["sigrok"]
# The file holds 0.52 s; the run needs its 0.5 s and the 60 us the board is late. A replay that
# has not delivered the rest when the run ends is stopped then (under load sigrok-cli took 1.3 s
# to start and the run stopped it 3712 samples short): at least the run's span, at most the file.
assert sg["input_file"].endswith("board.sr") and 1000120 <= sg["samples"] <= 1040000 and sg["exit_status"] == 0, sg
assert ro["abz"]["illegal_transitions"] == 10 and ro["abz"]["missed_index"] == 2 and ro["abz"]["index_errors"] == 0, ro["abz"]
assert abs(ro["latency_s"] - 60e-6) < 0.03 * 60e-6, ro["latency_s"]
step = 2 * math.pi / 64
assert abs(ro["rms_without_latency_rad"] - step / math.sqrt(12)) < 0.1 * step / math.sqrt(12), ro["rms_without_latency_rad"]
assert m["slipped_samples"] == 0
wire = [x for x in r["measurements"] if x["metric"] == "dut_wire_errors"]
assert wire and wire[0]["value"] == 12 and wire[0]["outcome"] == "PASS", wire
assert "dut_wire_errors" in [w["code"] for w in r["warnings"]]
assert [e for e in r["estimators"] if e["label"] == "atan2"][0]["metrics"]["evidence"]["scored_samples"] > 40000
print("whole bench ok: latency", ro["latency_s"], "rms without latency", ro["rms_without_latency_rad"], "wire errors 12")
PY
echo "cli_dut_readout: ok"
