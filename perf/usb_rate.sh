#!/usr/bin/env bash
# Sustained streaming through the emulated USB board (fringe-usb-sim, umockdev): the highest
# rate that runs 2 s with zero dropped samples and no underflow, each way (DAC out, ADC in).
# Any lost sample ends a run as ERROR, so PASS at a rate means zero drops at that rate.
#   perf/usb_rate.sh build/server/fringe-usb-sim
set -euo pipefail
SIM="${1:-build/server/fringe-usb-sim}"; SRC="$(cd "$(dirname "$0")/.." && pwd)"
PY=/usr/bin/python3
# The free-running board at full speed, whatever the caller's environment says.
export FRINGE_USB_EMULATOR_CLOCK=realtime FRINGE_USB_EMULATOR_TIME_SCALE=1
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
for rate in 500000 1000000 1500000 2000000 4000000; do
  $PY - "$SRC" "$rate" "$dir/s.json" <<'PY'
import json, sys
src, rate, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
sc = json.load(open(src + "/fixtures/scenarios/usb-stream.json"))
sc["encoder"] = src + "/fixtures/encoders/paper-d2-analog.json"
sc["sample_rate_hz"] = rate
sc["duration_s"] = 2.0
sc["motion"] = {"kind": "constant", "electrical_freq_hz": rate / 937.0}
sc["estimators"] = [{"name": "atan2"}]
sc["limits"] = []
json.dump(sc, open(out, "w"))
PY
  t0=$(date +%s.%N)
  set +e
  "$SIM" run "$dir/s.json" --no-db -q --report "$dir/r.json" 2> "$dir/err.txt"; rc=$?
  set -e
  t1=$(date +%s.%N)
  $PY - "$dir/r.json" "$rate" "$t0" "$t1" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); rate = float(sys.argv[2]); wall = float(sys.argv[4]) - float(sys.argv[3])
n = r["samples"]["processed"]
print(f"{rate/1e6:4.1f} MS/s: {r['verdict']:5s} {n} sample pairs each way in {wall:.2f} s wall"
      + (f"  ({r['error'][:160]})" if r.get("error") else ""))
PY
done
