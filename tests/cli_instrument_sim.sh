#!/usr/bin/env bash
# SCPI instruments end to end through the real CLI and TCP, all on 127.0.0.1:
#  - fixtures/scenarios/scpi-awg-digitizer.json on `fringe instrument-sim --bench` (free ports):
#    PASS, and the report's alignment gives back the bench link (256 samples of pretrigger +
#    15 us, 20 ppm, gain 0.95);
#  - another generator dialect and link (Rigol, 40 us, -35 ppm): the alignment follows the sim;
#  - a Red Pitaya pair (one URI plays and records) on its 16384-sample buffer;
#  - an instrument killed mid-run ends the run as ERROR naming it; bad options exit 2;
#  - faults mid-acquisition (killed, frozen, a block cut short, late replies) under `fringe run`
#    and `fringe serve`: ERROR with its reason and partial report, the service stays up;
#  - hostile instrument text: a 10 MB *IDN?, escape sequences and NUL in *IDN? and the error
#    queue, and in a scenario name, never reach the terminal raw.
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
# 6. Issue 22: the digitizer dies mid-acquisition (at its first :WAV:DATA?, the generator
#    playing). Before: the frame source's destructor stopped the generator, that threw during
#    the unwinding, std::terminate, exit 134, no report. Now: exit 2, ERROR with the reason, the
#    partial report (its playback) kept, the history row error with the reason.
D="$dir/data"
isim killed --bench --fault drop --fault-on ':WAV:DATA?'
scenario "$dir/killed.json" "$GEN?model=keysight-33500b&timeout_s=1" "$DIG?model=generic-scope&timeout_s=1"
set +e
"$FRINGE" run "$dir/killed.json" --data "$D" --report "$dir/killed-report.json" > "$dir/killed-run.out" 2> "$dir/killed-run.log"
rc=$?
set -e
[ $rc -eq 2 ] || fail "an instrument killed mid-acquisition: exit 2 expected, got $rc (134: std::terminate)"
grep -q "WAV:DATA" "$dir/killed-run.log" || fail "the error should name the command the instrument died at"
jq -e '.status == "error" and .verdict == "ERROR" and (.error | test("record: .*connection"))' "$dir/killed-report.json" > /dev/null \
  || fail "killed: report status/error $(jq -c '{status,error}' "$dir/killed-report.json")"
jq -e '.alignment.playback.samples > 0 and .device.uri != null' "$dir/killed-report.json" > /dev/null || fail "killed: the partial report lost its playback/device"
kid=$(jq -r .id "$dir/killed-report.json")
"$FRINGE" runs --data "$D" --json | jq -e --arg id "$kid" '.[] | select(.id == $id) | .status == "error" and .verdict == "ERROR"' > /dev/null \
  || fail "killed: the history row should be error/ERROR"
"$FRINGE" runs --data "$D" --show "$kid" > "$dir/killed-show.out" 2>&1 || true
grep -q "error: .*record: .*connection" "$dir/killed-show.out" || fail "killed: runs --show should give the reason: $(cat "$dir/killed-show.out")"
wait $SIM_PID 2>/dev/null || true

# 7. Frozen mid-acquisition: a timeout naming the command, within timeout x (a few reads).
isim frozen --bench --fault freeze --fault-on ':WAV:DATA?'
scenario "$dir/frozen.json" "$GEN?model=keysight-33500b&timeout_s=0.5" "$DIG?model=generic-scope&timeout_s=0.5"
t0=$(date +%s.%N)
set +e
"$FRINGE" run "$dir/frozen.json" --no-db -q --report "$dir/frozen-report.json" > "$dir/frozen-run.log" 2>&1
rc=$?
set -e
t1=$(date +%s.%N)
[ $rc -eq 2 ] || fail "a frozen instrument: exit 2 expected, got $rc"
jq -e '.status == "error" and (.error | test("timeout waiting for the block answering .:WAV:DATA\\?"))' "$dir/frozen-report.json" > /dev/null \
  || fail "frozen: $(jq -c '{status,error}' "$dir/frozen-report.json")"
$PY -c "import sys; d=$t1-$t0; print('frozen: ERROR after %.2f s' % d); sys.exit(d > 20)" || fail "frozen: too slow"
kill $SIM_PID 2>/dev/null || true

# 8. A block cut short (half of the :WAV:DATA? reply, then silence): "truncated block", with the
#    counts, not "no reply within".
isim cut --bench --fault truncate --fault-on ':WAV:DATA?'
scenario "$dir/cut.json" "$GEN?model=keysight-33500b&timeout_s=0.5" "$DIG?model=generic-scope&timeout_s=0.5"
set +e
"$FRINGE" run "$dir/cut.json" --no-db -q --report "$dir/cut-report.json" > "$dir/cut-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 2 ] || fail "a truncated block: exit 2 expected, got $rc"
jq -e '.error | test("truncated block: [0-9]+ of [0-9]+ declared bytes arrived within 0.5 s")' "$dir/cut-report.json" > /dev/null \
  || fail "truncated block: $(jq -c .error "$dir/cut-report.json")"
kill $SIM_PID 2>/dev/null || true

# 9. Every reply later than the timeout: ERROR at once (the *IDN? at open), exit 2.
isim slow --bench --reply-delay-s 1.5
scenario "$dir/slow.json" "$GEN?model=keysight-33500b&timeout_s=0.3" "$DIG?model=generic-scope&timeout_s=0.3"
set +e
"$FRINGE" run "$dir/slow.json" --no-db -q --report "$dir/slow-report.json" > "$dir/slow-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 2 ] && grep -q "no reply within 0.3 s" "$dir/slow-run.log" || fail "delayed replies: exit 2 naming the timeout expected (rc $rc)"
kill $SIM_PID 2>/dev/null || true

# 10. Issue 21: a 10 MB *IDN? (model=auto): refused at 256 bytes, a short error and report.
isim longidn --bench --idn-bytes 10000000
scenario "$dir/longidn.json" "$GEN?model=auto&timeout_s=2" "$DIG?model=generic-scope"
set +e
"$FRINGE" run "$dir/longidn.json" --no-db -q --report "$dir/longidn-report.json" > "$dir/longidn-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 2 ] || fail "a 10 MB *IDN?: exit 2 expected, got $rc"
grep -q "reply longer than 256 bytes" "$dir/longidn-run.log" || fail "a 10 MB *IDN? should be refused naming the cap"
for f in "$dir/longidn-run.log" "$dir/longidn-report.json"; do
  [ "$(stat -c %s "$f")" -lt 65536 ] || fail "$f holds $(stat -c %s "$f") bytes after a 10 MB *IDN?"
done
kill $SIM_PID 2>/dev/null || true

# 11. Escape sequences from instruments and scenarios never reach the terminal raw: the
#     digitizer's *IDN? (the run's DUT), an error-queue text with ESC, BEL, NUL and a byte that
#     is not UTF-8, and a scenario name with ESC. No raw ESC in any output; NUL shown, not cut.
no_raw_esc() {  # FILE...: no ESC (0x1b), BEL or NUL byte, and no 0x9b (C1 CSI) byte
  for f in "$@"; do
    if LC_ALL=C grep -q -P '[\x1b\x07\x00\x9b]' "$f"; then fail "raw control bytes in $f: $(od -c "$f" | grep -m3 '033\|\\0\|\\a')"; fi
  done
}
E="$dir/esc-data"
isim esc --bench --digitizer-idn 'FRINGE,\x1b]0;pwned\x07\x1b[2J,SN\x00tail\xff,1.0' --error-on ':WAV:STAR' --error-text 'bad \x1b[31mred\x1b[0m \xc2\x9b2J\x00kept\xfe'
scenario "$dir/esc.json" "$GEN?model=keysight-33500b&timeout_s=1" "$DIG?model=generic-scope&timeout_s=1" '| .name = "evil\u001b[2J\u001b]0;title\u0007name"'
set +e
"$FRINGE" run "$dir/esc.json" --data "$E" --report "$dir/esc-report.json" > "$dir/esc-run.out" 2> "$dir/esc-run.log"
rc=$?
set -e
[ $rc -eq 2 ] || fail "the instrument error should end the run as ERROR (rc $rc)"
eid=$(jq -r .id "$dir/esc-report.json")
"$FRINGE" runs --data "$E" > "$dir/esc-runs.out" 2> "$dir/esc-runs.log"
"$FRINGE" runs --data "$E" --show "$eid" > "$dir/esc-show.out" 2> "$dir/esc-show.log" || true
no_raw_esc "$dir/esc-run.out" "$dir/esc-run.log" "$dir/esc-runs.out" "$dir/esc-runs.log" "$dir/esc-show.out" "$dir/esc-show.log"
grep -qF 'red\x1b[0m \u009b2J\x00kept\xfe' "$dir/esc-run.log" || fail "the error text should be whole and escaped: $(cat "$dir/esc-run.log")"
grep -qF 'evil\x1b[2J\x1b]0;title\x07name' "$dir/esc-runs.out" || fail "fringe runs: the scenario name escaped: $(cat "$dir/esc-runs.out")"
grep -qF 'SN\x00tail\xff' "$dir/esc-runs.out" || fail "fringe runs: the DUT (*IDN?) escaped and whole: $(cat "$dir/esc-runs.out")"
grep -qF 'evil\x1b[2J' "$dir/esc-show.out" || fail "runs --show: the name escaped: $(cat "$dir/esc-show.out")"
kill $SIM_PID 2>/dev/null || true

# 12. The same death under `fringe serve --allow-device 'scpi+tcp://*'`: before, the whole
#     service exited (std::terminate). Now the run is stored as error with its reason, the
#     service stays up and health answers.
S="$dir/serve-data"
"$FRINGE" serve --bind 127.0.0.1:0 --data "$S" --workers 1 --allow-device 'scpi+tcp://*' > "$dir/serve.out" 2> "$dir/serve.log" &
SERVE_PID=$!; pids+=($SERVE_PID)
URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 200 0.1) || fail "fringe serve did not start"
isim killed2 --bench --fault drop --fault-on ':WAV:DATA?'
scenario "$dir/killed2.json" "$GEN?model=keysight-33500b&timeout_s=1" "$DIG?model=generic-scope&timeout_s=1"
sid=$(jq -c '{scenario: .}' "$dir/killed2.json" | curl -sS --max-time 10 -X POST -H "Authorization: Bearer $(cat "$S/token")" --data-binary @- "${URL}api/v1/runs" | jq -r .id)
[ -n "$sid" ] && [ "$sid" != null ] || fail "POST /runs did not start the run"
st=""
for _ in $(seq 200); do
  st=$(curl -sS --max-time 5 "${URL}api/v1/runs/$sid" | jq -r '.status' 2>/dev/null || true)
  case "$st" in error|done|aborted|interrupted) break ;; esac
  kill -0 $SERVE_PID 2>/dev/null || fail "fringe serve exited during the run: $(tail -5 "$dir/serve.log")"
  sleep 0.1
done
kill -0 $SERVE_PID 2>/dev/null || fail "fringe serve exited when the instrument died: $(tail -5 "$dir/serve.log")"
[ "$st" = error ] || fail "serve: the run should end as error, is '$st'"
curl -sS --max-time 5 "${URL}api/v1/runs/$sid" | jq -e '.verdict == "ERROR" and (.error | test("record: .*connection"))' > /dev/null \
  || fail "serve: the run's error: $(curl -sS --max-time 5 "${URL}api/v1/runs/$sid")"
curl -sS --max-time 5 "${URL}api/v1/runs/$sid/report.json" | jq -e '.status == "error" and .alignment.playback.samples > 0' > /dev/null \
  || fail "serve: the stored report should be the partial one"
[ "$(curl -sS --max-time 1 -o /dev/null -w '%{http_code}' "${URL}api/v1/health")" = 200 ] || fail "serve: health should answer after the failed run"
kill $SERVE_PID; wait $SERVE_PID 2>/dev/null || true

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

# 7. A non-periodic run (a ramp) longer than the generator's memory: the Keysight has no
#    segmented playback over SCPI, so the run is refused naming the memory and why, through the
#    real driver over TCP (docs/bench.md "Segmented playback").
isim seg --bench --memory-samples 20000
scenario "$dir/seg.json" "$GEN?model=keysight-33500b&memory_samples=20000" "$DIG?model=generic-scope&pretrigger_samples=256" \
  '| .motion = {"kind": "ramp", "velocity_rad_s": 6.1359, "accel_rad_s2": 12.272} | .duration_s = 0.3'
set +e
"$FRINGE" run "$dir/seg.json" --no-db -q --report "$dir/seg-report.json" > "$dir/seg-run.log" 2>&1
rc=$?
set -e
[ $rc -eq 2 ] || fail "a ramp beyond the Keysight's memory should end as ERROR (exit 2), got $rc"
jq -e '.error | test("holds 20000 \\(max_play_samples\\)") and test("cannot play it in segments") and test("DATA:SEQuence")' "$dir/seg-report.json" > /dev/null \
  || fail "the refusal names the memory and the Keysight's reason: $(jq .error "$dir/seg-report.json")"
echo "cli_instrument_sim: ok"
