#!/usr/bin/env bash
# LabJack T4/T7/T8 board profiles end to end: the real `fringe run` (step mode over Modbus TCP)
# against pymodbus (Debian's python3-pymodbus) emulating a LabJack's registers on 127.0.0.1
# (tests/pymodbus_labjack.py, DAC0->AIN0 and DAC1->AIN1 looped):
#  - fixtures/scenarios/labjack-t7-step.json passes; the report's converter is the profile's
#    (12-bit 0..5 V DAC, 16-bit +-10 V ADC) and the bound uses it; the init writes reached the
#    device; FLOAT32 went over function 16 only;
#  - a profile with the wrong word order fails at open naming the word order, and without its
#    checks it still ends as ERROR (a refused init value, or a misread AIN), never a PASS;
#  - function 6 on the FLOAT32 DAC registers is refused by the emulated T7 and ends the run as
#    ERROR naming the register and the function;
#  - a T4 profile on a T7 names the product id it found; the T4 and T8 profiles pass on their
#    emulated models.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pids=()
trap 'for p in "${pids[@]}"; do kill $p 2>/dev/null || true; done; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; for f in "$dir"/*.log; do echo "== $f" >&2; tail -n 40 "$f" >&2; done; exit 1; }
S="$SRC/fixtures/scenarios/labjack-t7-step.json"

emu() {  # emu NAME ARGS...: start the emulator on a free port, set PORT
  local name=$1; shift
  PORT=$($PY -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
  timeout 120 $PY "$SRC/tests/pymodbus_labjack.py" "$PORT" "$@" > "$dir/$name.log" 2>&1 &
  pids+=($!)
  poll_log "$dir/$name.log" 's/^listening \(.*\)$/\1/p' 100 0.1 > /dev/null || fail "emulator $name did not start"
}
profile() {  # profile OUT PYTHON-EXPR-ON-p: a modified copy of labjack-t7.json
  $PY - "$SRC/fixtures/boards/labjack-t7.json" "$1" "$2" <<'PY'
import json, sys
p = json.load(open(sys.argv[1]))
exec(sys.argv[3])
json.dump(p, open(sys.argv[2], "w"))
PY
}
run() {  # run NAME URI: fringe run the fixture at URI; sets rc
  set +e
  timeout 60 "$FRINGE" run "$S" --no-db -q --device "$2" --report "$dir/$1.json" > "$dir/$1.out" 2>&1; rc=$?
  set -e
}

# 1. The fixture on an emulated T7.
emu t7 --model t7 --seed 3
run t7 "modbus+tcp://127.0.0.1:$PORT?board=labjack-t7"
[ $rc -eq 0 ] || fail "labjack-t7-step should pass on the emulated T7 (exit $rc): $(cat "$dir/t7.out")"
$PY - "$dir/t7.json" <<'PY' || fail "T7 report"
import json, sys
r = json.load(open(sys.argv[1]))
assert r["verdict"] == "PASS" and r["status"] == "done", (r["verdict"], r["error"])
assert r["samples"]["processed"] == 128, r["samples"]
d = r["device"]
assert d["driver"] == "modbus" and d["board_id"].startswith("labjack-t7@127.0.0.1:"), d
c = d["converter"]
# The profile's converters: DAC 12 bits over 0..5 V, ADC 16 bits over +-10 V (register units),
# ranges as seen from the signal's zero at 2.5 V.
assert c["known"] and c["dac_bits"] == 12 and c["adc_bits"] == 16, c
assert abs(c["dac_step_v"] - 5 / 4096) < 1e-12 and abs(c["adc_step_v"] - 20 / 65536) < 1e-12, c
assert abs(c["dac_range_v"] - 2.5) < 1e-12 and abs(c["adc_range_v"] - 7.5) < 1e-12, c
assert "sin_out 12 bits over 0..5 V" in c["note"], c["note"]
est = {e["label"]: e for e in r["estimators"]}["atan2"]
m = est["metrics"]
# atan2 on the paper's diffraction signal: about 1.8e-2 rad rms from its harmonics (as through
# board-sim in cli_modbus.sh); the LabJack's quantisation adds ~4e-4 rad, invisible beside it.
assert 0.015 < m["rms"]["rad"] < 0.021 and m["slipped_samples"] == 0 and m["scored"] == 128, m
# The bound's noise basis carries the device's converter steps; the signal fits the DAC (no
# clipping warning).
b = est["bounds"]["signal_as_delivered"]
assert b["device_dac_step_v"] == 5 / 4096 and b["device_adc_step_v"] == 20 / 65536, b
assert not [w for w in r["warnings"] if "clip" in json.dumps(w)], r["warnings"]
PY
for want in "write AIN0_NEGATIVE_CH = 199" "write AIN1_NEGATIVE_CH = 199" "write AIN0_RANGE = 10" "write AIN1_RANGE = 10" \
            "write AIN0_RESOLUTION_INDEX = 8" "write AIN1_RESOLUTION_INDEX = 8"; do
  grep -qx "$want" "$dir/t7.log" || fail "the T7 saw no '$want'"
done
! grep -q '^refused' "$dir/t7.log" || fail "the T7 refused a request of the good profile: $(grep '^refused' "$dir/t7.log")"

# 2. Wrong word order: a clear failure at open, naming it (and no configuration written).
profile "$dir/p-little.json" 'p["word_order"] = "little"'
run little "modbus+tcp://127.0.0.1:$PORT?board=$dir/p-little.json"
[ $rc -eq 2 ] || fail "a little-endian word order on a T7 should end as ERROR (exit 2), got $rc"
grep -q "check TEST @55100 reads 573767697, expected 1122867" "$dir/little.json" \
  || fail "the error names the TEST check: $(cat "$dir/little.out")"
grep -q "the profile's word_order 'little' is not the board's" "$dir/little.json" || fail "the error names the word order"
#    ... and without the checks the run still stops: the T7 refuses the garbled init values
#    (an AIN range of 2.3e-41 V), and with no init either the garbled drive values never
#    reach the inputs, which read one value while the signal moves: a frozen input, naming the
#    word order among its causes. Never a garbage PASS.
profile "$dir/p-nocheck.json" 'p["word_order"] = "little"; p.pop("checks")'
run nocheck "modbus+tcp://127.0.0.1:$PORT?board=$dir/p-nocheck.json"
[ $rc -eq 2 ] || fail "a wrong word order without checks must end as ERROR, got $rc"
grep -q "init AIN0_RANGE=10 @40000: Slave device or server failure" "$dir/nocheck.json" || fail "the error names the refused init write: $(cat "$dir/nocheck.out")"
grep -q '^refused value AIN0_RANGE = 2.3' "$dir/t7.log" || fail "the emulator saw the garbled range"
profile "$dir/p-bare.json" 'p["word_order"] = "little"; p.pop("checks"); p.pop("init")'
run bare "modbus+tcp://127.0.0.1:$PORT?board=$dir/p-bare.json"
[ $rc -eq 2 ] || fail "a wrong word order without checks or init must end as ERROR, got $rc"
$PY - "$dir/bare.json" <<'PY' || fail "bare report"
import json, sys
r = json.load(open(sys.argv[1]))
assert r["verdict"] == "ERROR", r["verdict"]
# The garbled drive values never reach the inputs: they read one value while the signal moves.
assert "bench: the input of modbus+tcp://127.0.0.1:" in r["error"] and "is frozen: 32 consecutive samples from input sample 0 read exactly" in r["error"] \
    and "word order" in r["error"], r["error"]
PY

# 3. Function 6 on the FLOAT32 DACs: the T7 refuses it; the run ends as ERROR naming it.
profile "$dir/p-fc6.json" 'p["registers"]["sin_out"]["write_function"] = 6; p["registers"]["cos_out"]["write_function"] = 6'
run fc6 "modbus+tcp://127.0.0.1:$PORT?board=$dir/p-fc6.json"
[ $rc -eq 2 ] || fail "function 6 writes to a T7's DAC should end as ERROR (exit 2), got $rc"
$PY - "$dir/fc6.json" <<'PY' || fail "fc6 report"
import json, sys
r = json.load(open(sys.argv[1]))
assert r["verdict"] == "ERROR", r["verdict"]
assert "write sin_out @1000 (function 6, word 0): Illegal data address" in r["error"], r["error"]
PY
grep -q '^refused fc=6 @1000+1$' "$dir/t7.log" || fail "the emulator saw function 6 on DAC0"

# 4. The wrong model: a T4 profile on a T7.
run t4on7 "modbus+tcp://127.0.0.1:$PORT?board=labjack-t4"
[ $rc -eq 2 ] || fail "a T4 profile on a T7 should end as ERROR (exit 2), got $rc"
grep -q "check PRODUCT_ID @60000 reads 7, expected 4" "$dir/t4on7.json" || fail "the error names the product id: $(cat "$dir/t4on7.out")"

# 5. The T4 and T8 profiles on their emulated models (same map, other converters).
for model in t4 t8; do
  emu "$model" --model "$model" --seed 5
  run "run-$model" "modbus+tcp://127.0.0.1:$PORT?board=labjack-$model"
  [ $rc -eq 0 ] || fail "labjack-$model should pass on its emulated model (exit $rc): $(cat "$dir/run-$model.out")"
done
$PY - "$dir/run-t4.json" "$dir/run-t8.json" <<'PY' || fail "T4/T8 reports"
import json, sys
t4, t8 = (json.load(open(p))["device"]["converter"] for p in sys.argv[1:3])
assert t4["dac_bits"] == 10 and abs(t4["dac_step_v"] - 5 / 1024) < 1e-12 and t4["adc_bits"] == 12, t4
assert t8["dac_bits"] == 16 and abs(t8["dac_step_v"] - 10.1 / 65536) < 1e-12 and t8["adc_bits"] == 15, t8
PY
grep -qx "write AIN0_RESOLUTION_INDEX = 5" "$dir/t4.log" || fail "the T4 saw its resolution index"
grep -qx "write AIN0_RANGE = 11" "$dir/t8.log" || fail "the T8 saw its AIN range"
echo "cli.labjack: ok"
