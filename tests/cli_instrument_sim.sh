#!/usr/bin/env bash
# SCPI instruments end to end through the real CLI and TCP, all on 127.0.0.1:
#  - fixtures/scenarios/scpi-awg-digitizer.json on `fringe instrument-sim --bench` (free ports):
#    PASS, and the report's alignment gives back the bench link (256 samples of pretrigger +
#    15 us, 20 ppm, gain 0.95);
#  - another generator dialect and link (Rigol, 40 us, -35 ppm): the alignment follows the sim;
#  - a Red Pitaya pair (one URI plays and records) on its 16384-sample buffer;
#  - an instrument killed mid-run ends the run as ERROR naming it; bad options exit 2.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pids=()
trap 'for p in "${pids[@]}"; do kill $p 2>/dev/null || true; done; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; for f in "$dir"/*.log; do echo "== $f" >&2; cat "$f" >&2; done; exit 1; }
F="$SRC/fixtures/scenarios/scpi-awg-digitizer.json"

isim() {  # isim NAME ARGS...: start instrument-sim on free ports, set GEN and DIG (URIs without query)
  local name=$1; shift
  "$FRINGE" instrument-sim --port 0 --exit-after 100 "$@" > "$dir/$name.log" 2>&1 &
  pids+=($!); SIM_PID=$!
  GEN=$(poll_log "$dir/$name.log" 's/^instrument-sim generator \(scpi[^?]*\).*/\1/p') || fail "instrument-sim $name did not start"
  DIG=$(poll_log "$dir/$name.log" 's/^instrument-sim digitizer \(scpi[^?]*\).*/\1/p') || fail "instrument-sim $name did not start"
}
scenario() {  # scenario OUT GEN_URI DIG_URI [JQ]: the fixture with its instruments (and more) replaced
  jq --arg g "$2" --arg d "$3" ".device.output=\$g | .device.input=\$d ${4:-}" "$F" > "$1"
}
check_alignment() {  # REPORT DELAY_S PPM GAIN
  $PY - "$@" <<'PY' || fail "alignment in $1"
import json, sys
r = json.load(open(sys.argv[1]))
a = r["alignment"]
delay, ppm, gain = map(float, sys.argv[2:5])
assert a["ok"], a
assert abs(a["delay_s"] - delay) < 2e-8, (a["delay_s"], delay)
assert abs(a["clock_offset_ppm"] - ppm) < 0.05, (a["clock_offset_ppm"], ppm)
for ch in ("sin", "cos"):
    assert abs(a["channels"][ch]["gain"] - gain) < 1e-3, (ch, a["channels"][ch], gain)
print("alignment ok:", a["delay_s"], a["clock_offset_ppm"])
PY
}

# 1. The fixture on the emulated bench.
isim bench --bench
scenario "$dir/bench.json" "$GEN?model=keysight-33500b" "$DIG?model=generic-scope&pretrigger_samples=256"
"$FRINGE" run "$dir/bench.json" --no-db -q --report "$dir/bench-report.json" > "$dir/bench-run.log" 2>&1 || fail "the fixture should PASS on instrument-sim --bench"
jq -e '.verdict == "PASS"' "$dir/bench-report.json" > /dev/null || fail "verdict"
check_alignment "$dir/bench-report.json" "$($PY -c 'print(256/1e5 + 15e-6)')" 20 0.95
kill $SIM_PID; wait $SIM_PID 2>/dev/null || true
grep -q "commands answered" "$dir/bench.log" || fail "instrument-sim did not stop cleanly on SIGTERM"

# 2. Another dialect and link: the measured alignment follows the sim's settings.
isim rigol --generator rigol-dg1000z --delay-s 4e-5 --clock-ppm -35 --gain 1.1 --noise-v 1e-4
scenario "$dir/rigol.json" "$GEN?model=rigol-dg1000z" "$DIG?model=generic-scope&pretrigger_samples=500" \
  '| .limits |= map(select(.metric | startswith("align") or startswith("clock") | not))'
"$FRINGE" run "$dir/rigol.json" --no-db -q --report "$dir/rigol-report.json" > "$dir/rigol-run.log" 2>&1 || fail "the Rigol bench should PASS"
check_alignment "$dir/rigol-report.json" "$($PY -c 'print(500/1e5 + 4e-5)')" -35 1.1

# 3. A Red Pitaya plays and records on one URI (125 MHz / 1000, 16384-sample buffer).
isim rp --generator redpitaya --digitizer redpitaya --delay-s 1e-5 --clock-ppm 15
[ "$GEN" = "$DIG" ] || fail "a Red Pitaya pair shares one port"
scenario "$dir/rp.json" "$GEN?model=redpitaya&pretrigger_samples=400" "$GEN?model=redpitaya&pretrigger_samples=400" \
  '| .sample_rate_hz = 125000 | .duration_s = 0.09 | .settle_s = 0.02 | .encoder.vmax_v = 0.8 | .motion.electrical_freq_hz = 1562.5 | .limits |= map(select(.metric | startswith("align") or startswith("clock") | not))'
"$FRINGE" run "$dir/rp.json" --no-db -q --report "$dir/rp-report.json" > "$dir/rp-run.log" 2>&1 || fail "the Red Pitaya bench should PASS"
check_alignment "$dir/rp-report.json" "$($PY -c 'print(400/125e3 + 1e-5)')" 15 1.0

# 4. The digitizer dies before the record: ERROR naming the instrument, exit 2.
isim dies --drop-after 40
scenario "$dir/dies.json" "$GEN?model=keysight-33500b&timeout_s=1" "$DIG?model=generic-scope"
set +e
"$FRINGE" run "$dir/dies.json" --no-db -q --report "$dir/dies-report.json" > "$dir/dies-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 2 ] || fail "a run whose instrument is gone should exit 2, got $rc"
grep -qi "connection\|scpi" "$dir/dies-run.log" || fail "the error should name the lost instrument"

# 5. Bad options are errors.
set +e
"$FRINGE" instrument-sim --generator no-such-awg --port 0 --exit-after 1 > "$dir/bad.log" 2>&1
rc=$?
set -e
[ $rc -eq 2 ] && grep -q "unknown generator 'no-such-awg'" "$dir/bad.log" || fail "an unknown generator should exit 2 naming it (rc $rc)"
sed -n 1p "$dir/dies-run.log"

# 6. A digitizer whose range (+-0.8 V) is below the signal (~1.1 V) clips: a bench ERROR naming
#    the digitizer and the share of samples on its rail, not a FAIL of the DUT.
isim clip --bench --digitizer-range-v 0.8
scenario "$dir/clip.json" "$GEN?model=keysight-33500b" "$DIG?model=generic-scope&pretrigger_samples=256"
set +e
"$FRINGE" run "$dir/clip.json" --no-db -q --report "$dir/clip-report.json" > "$dir/clip-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 2 ] || fail "a clipping digitizer should end the run as ERROR (exit 2), got $rc"
grep -q "bench: clipping at the input of $DIG?model=generic-scope.* % of sin samples (.*) sit on its largest value, 0.8 V" "$dir/clip-report.json" \
  || fail "the clipping error names the digitizer and the evidence: $(cat "$dir/clip-run.log")"
echo "cli_instrument_sim: ok"
