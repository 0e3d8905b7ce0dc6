#!/usr/bin/env bash
# USB through the real executable with the emulated board (fringe-usb-sim, umockdev preload;
# ctest runs it paced by the host, FRINGE_USB_EMULATOR_CLOCK=paced, so a stalled CI host cannot
# starve it): the usb-stream fixture passes; dropped frames, a stall and an unplug end the run
# as ERROR (exit 2) with exact counts; the device is listed by `devices --probe`.
set -euo pipefail
SIM="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
S="$SRC/fixtures/scenarios/usb-stream.json"

"$SIM" devices --probe usb:1209:ec01 > "$dir/dev.txt" || fail "devices --probe usb"
grep -q "usb:1209:ec01 .*fringe-usb-sim#SIM0001" "$dir/dev.txt" || fail "probe output: $(cat "$dir/dev.txt")"
# enumerated without being named
FRINGE_USB_EMULATOR="serial=E77" "$SIM" devices --json > "$dir/dev.json" || fail "devices --json"
$PY -c 'import json,sys; d=json.load(open(sys.argv[1]))
assert any(r["uri"] == "usb:1209:ec01?serial=E77" for r in d["reachable"]), d["reachable"]' "$dir/dev.json" || fail "USB board not enumerated"

"$SIM" run "$S" --no-db -q --report "$dir/ok.json" || fail "usb-stream should pass"
$PY - "$dir/ok.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
assert r["verdict"] == "PASS" and r["samples"]["processed"] == 2000000, (r["verdict"], r["error"], r["samples"])
assert r["device"]["driver"] == "usb" and r["device"]["settings"]["frame_samples"] == 16384, r["device"]
PY

run_fault() {  # run_fault SPEC NAME: the run must end as ERROR (exit 2)
  set +e
  FRINGE_USB_EMULATOR="$1" "$SIM" run "$S" --no-db -q --report "$dir/$2.json"; local rc=$?
  set -e
  [ $rc -eq 2 ] || fail "$2: expected exit 2, got $rc"
}
run_fault "drop_at=20,drop_count=2" drop
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); e=r["error"]
assert r["verdict"]=="ERROR" and "32768 input samples dropped before input sample 327680" in e, e' "$dir/drop.json" || fail "drop report: $(cat "$dir/drop.json" | head -c 400)"
run_fault "stall_after=10" stall
grep -q "stall on IN endpoint 0x81" "$dir/stall.json" || fail "stall report"
run_fault "unplug_after=30" unplug
grep -q "device unplugged" "$dir/unplug.json" || fail "unplug report"
echo "cli.usb: ok"
