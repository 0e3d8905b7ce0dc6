#!/usr/bin/env bash
# Modbus end to end with real transports and third-party peers, all on 127.0.0.1 or a pty:
#  - fringe run (step mode) against board-sim over TCP and over RTU on a socat pty pair;
#  - mbpoll (Debian) writing and reading board-sim's registers;
#  - pymodbus (Debian's python3-pymodbus) as the analog module fringe drives in step mode;
#  - a board that drops mid-run ends the run as ERROR naming it;
#  - one owner per board: a second process on it (spelt 127.1) is refused as busy;
#  - a board that clips or repeats old data is a bench ERROR, not a FAIL of the DUT.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pids=()
trap 'for p in "${pids[@]}"; do kill $p 2>/dev/null || true; done; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; for f in "$dir"/*.log; do echo "== $f" >&2; cat "$f" >&2; done; exit 1; }
S="$SRC/fixtures/scenarios/modbus-step-sweep.json"

sim() {  # sim NAME ARGS...: start board-sim, set SIM_URL (tcp) from its output
  local name=$1; shift
  timeout 120 "$FRINGE" board-sim "$@" > "$dir/$name.log" 2>&1 &
  pids+=($!)
  SIM_AT=$(poll_log "$dir/$name.log" 's/.* listening on \(.*\)$/\1/p') || fail "board-sim $name did not start"
}
port_of() { echo "${1##*:}"; }

# 1. TCP: the fixture against an emulated DUT board.
sim dut --modbus tcp://127.0.0.1:0 --board dut-interpolator --noise-v 2e-4 --seed 3
P=$(port_of "$SIM_AT")
"$FRINGE" run "$S" --no-db -q --device "modbus+tcp://127.0.0.1:$P?board=dut-interpolator" --report "$dir/tcp.json" --junit "$dir/tcp.xml" \
  || fail "modbus-step-sweep over TCP should pass"
$PY - "$dir/tcp.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
assert r["verdict"] == "PASS" and r["status"] == "done", (r["verdict"], r["error"])
assert r["samples"]["processed"] == 128, r["samples"]
est = {e["label"]: e for e in r["estimators"]}
dut = est["dut"]["metrics"]
# The on-board atan2 on the paper's diffraction signal: MODEL.md 5 gives 1.8e-2 rad rms.
assert 0.015 < dut["rms"]["rad"] < 0.021, dut["rms"]
assert dut["slipped_samples"] == 0 and dut["scored"] == 128, dut
assert r["device"]["driver"] == "modbus" and r["device"]["board_id"].startswith("dut-interpolator@127.0.0.1:"), r["device"]
PY
grep -q 'classname="modbus-step-sweep.dut" name="rms_rad"' "$dir/tcp.xml" || fail "JUnit has the dut measurement"

# 2. mbpoll (third-party client) against a fresh board-sim: write the drive floats, read the position.
sim mb --modbus tcp://127.0.0.1:0 --board dut-interpolator --adc-bits 0
P=$(port_of "$SIM_AT")
timeout 10 mbpoll -q -m tcp -p "$P" -0 -r 100 -t 4:float -B -- 127.0.0.1 0.0 -1.0 > "$dir/mbw.log" 2>&1 || fail "mbpoll write"
timeout 10 mbpoll -q -m tcp -p "$P" -0 -r 0 -c 5 -t 3 -1 127.0.0.1 > "$dir/mbr.log" 2>&1 || fail "mbpoll read"
# theta = atan2(0, -1) = pi: count 0 (registers 0,1), fraction 0.5 -> 32768 (register 2), status 1, flags 0
for want in "\[0\]:[[:space:]]*0$" "\[1\]:[[:space:]]*0$" "\[2\]:[[:space:]]*32768 (-32768)$" "\[3\]:[[:space:]]*1$" "\[4\]:[[:space:]]*0$"; do
  grep -q "$want" "$dir/mbr.log" || fail "mbpoll read: expected $want in $(cat "$dir/mbr.log")"
done
timeout 10 mbpoll -q -m tcp -p "$P" -0 -r 100 -c 2 -t 4:float -B -1 127.0.0.1 > "$dir/mbf.log" 2>&1 || fail "mbpoll float read"
grep -q "\[102\]:[[:space:]]*-1$" "$dir/mbf.log" || fail "mbpoll reads back cos_out = -1: $(cat "$dir/mbf.log")"

# 3. RTU over a socat pty pair.
socat -d -d pty,raw,echo=0,link="$dir/ttyA" pty,raw,echo=0,link="$dir/ttyB" 2> "$dir/socat.log" &
pids+=($!)
for _ in $(seq 100); do [ -e "$dir/ttyA" ] && [ -e "$dir/ttyB" ] && break; sleep 0.05; done
sim rtu --modbus "rtu:$dir/ttyA" --board dut-interpolator --unit 7 --noise-v 2e-4
"$FRINGE" run "$S" --no-db -q --device "modbus+rtu:$dir/ttyB?board=dut-interpolator&unit=7&baud=115200" --report "$dir/rtu.json" \
  || fail "modbus-step-sweep over RTU should pass"
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); assert r["verdict"]=="PASS" and r["samples"]["processed"]==128, r["error"]' "$dir/rtu.json" \
  || fail "RTU report"
set +e
"$FRINGE" run "$S" --no-db -q --device "modbus+rtu:$dir/ttyB?board=dut-interpolator&unit=9&timeout_ms=100&retries=1" --report "$dir/rtu9.json"; rc=$?
set -e
[ $rc -eq 2 ] || fail "a unit id nobody answers should end as ERROR (exit 2), got $rc"
grep -q "timed out" "$dir/rtu9.json" || fail "unit 9: the error names the timeout"

# 4. pymodbus as the analog module, driven in step mode (limits on atan2 only: it has no DUT position).
PP=$($PY -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
timeout 120 $PY "$SRC/tests/pymodbus_aio.py" "$PP" 262 > "$dir/pymodbus.log" 2>&1 &
pids+=($!)
for _ in $(seq 100); do grep -q listening "$dir/pymodbus.log" && break; sleep 0.1; done
$PY - "$S" "$dir/aio.json" <<'PY'
import json, sys
sc = json.load(open(sys.argv[1]))
sc["encoder"] = sys.argv[1].rsplit("/", 2)[0] + "/encoders/paper-d2-analog.json"
sc["name"] = "pymodbus-aio"
sc["limits"] = [{"estimator": "atan2", "metric": "slipped_samples", "max": 0}]
json.dump(sc, open(sys.argv[2], "w"))
PY
"$FRINGE" run "$dir/aio.json" --no-db -q --device "modbus+tcp://127.0.0.1:$PP?board=generic-aio" --report "$dir/py.json" || fail "run against pymodbus"
$PY - "$dir/py.json" "$dir/tcp.json" <<'PY'
import cmath, json, sys
r = json.load(open(sys.argv[1]))
assert r["verdict"] == "PASS" and r["samples"]["processed"] == 128, r["error"]
def h1(path):
    rep = json.load(open(path))
    h = {e["label"]: e for e in rep["estimators"]}["atan2"]["metrics"]["harmonics"][0]
    return cmath.rect(h["amplitude"]["rad"], h["phase_rad"])
# The peer adds 262 counts (0.01 V) to sin. An offset o adds a 1x error of amplitude o/A
# (A = 1.093 V, the fundamental) to what atan2 shows on the same signals through board-sim.
extra = abs(h1(sys.argv[1]) - h1(sys.argv[2]))
assert abs(extra - 0.01 / 1.093) < 0.1 * 0.01 / 1.093, extra
PY

# 5. The board goes away mid-run: ERROR, naming the board.
sim drop --modbus tcp://127.0.0.1:0 --board dut-interpolator --drop-after 60
P=$(port_of "$SIM_AT")
set +e
"$FRINGE" run "$S" --no-db -q --device "modbus+tcp://127.0.0.1:$P?board=dut-interpolator&timeout_ms=200&retries=1" --report "$dir/drop.json"; rc=$?
set -e
[ $rc -eq 2 ] || fail "a lost board should end the run as ERROR (exit 2), got $rc"
$PY - "$dir/drop.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
assert r["verdict"] == "ERROR", r["verdict"]
assert "board dut-interpolator at 127.0.0.1:" in r["error"], r["error"]
assert r["samples"]["processed"] < 128, r["samples"]
PY
# 6. One owner per board across processes: while run A drives the board, run B on the same
#    board spelt 127.1 is refused (exit 2) naming A's pid; A is not disturbed and passes.
export FRINGE_LOCK_DIR="$dir/locks"
sim lock --modbus tcp://127.0.0.1:0 --board dut-interpolator --noise-v 2e-4 --seed 3 --delay-ms 4
P=$(port_of "$SIM_AT")
"$FRINGE" run "$S" --no-db -q --device "modbus+tcp://127.0.0.1:$P?board=dut-interpolator" --report "$dir/lockA.json" > "$dir/lockA.log" 2>&1 &
A=$!; pids+=($A)
for _ in $(seq 200); do grep -qs "^pid $A " "$dir"/locks/*.lock && break; sleep 0.02; done
grep -qs "^pid $A " "$dir"/locks/*.lock || fail "run A took no lock"
set +e
"$FRINGE" run "$S" --no-db -q --device "modbus+tcp://127.1:$P?board=dut-interpolator" --report "$dir/lockB.json" > "$dir/lockB.log" 2>&1; rc=$?
wait $A; rcA=$?
set -e
[ $rc -eq 2 ] || fail "a second run on a busy board should end as ERROR (exit 2), got $rc"
grep -q "busy: modbus-tcp:127.0.0.1:$P:unit1 is in use by pid $A (command [^)]*fringe run" "$dir/lockB.json" || fail "B names the board and A's pid: $(cat "$dir/lockB.log")"
[ $rcA -eq 0 ] || fail "run A should pass undisturbed, got $rcA: $(cat "$dir/lockA.log")"
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); assert r["samples"]["processed"]==128, r' "$dir/lockA.json" || fail "A ran every step"
"$FRINGE" run "$S" --no-db -q --device "modbus+tcp://127.1:$P?board=dut-interpolator" --report "$dir/lockC.json" || fail "the board is free once A ended"

# 6b. A serve run while a CLI run holds the board: the service's run ends as ERROR "busy"
#     naming the CLI run's pid; the service keeps serving.
timeout 120 "$FRINGE" serve --bind 127.0.0.1:0 --data "$dir/sdata" --allow-device 'modbus+tcp://127.*' > "$dir/serve.out" 2> "$dir/serve.log" &
SV=$!; pids+=($SV)
URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 100 0.1) || fail "fringe serve did not start"
P=$(port_of "$SIM_AT")
"$FRINGE" run "$S" --no-db -q --device "modbus+tcp://127.0.0.1:$P?board=dut-interpolator" --report "$dir/lockD.json" > "$dir/lockD.log" 2>&1 &
D=$!; pids+=($D)
for _ in $(seq 200); do grep -qs "^pid $D " "$dir"/locks/*.lock && break; sleep 0.02; done
body=$($PY -c 'import json,sys; sc=json.load(open(sys.argv[1])); sc["device"]=sys.argv[2]; print(json.dumps({"scenario": sc}))' "$S" "modbus+tcp://127.1:$P?board=dut-interpolator")
rid=$(curl -sS --max-time 10 -X POST -H "Authorization: Bearer $(cat "$dir/sdata/token")" -d "$body" "${URL}api/v1/runs" | $PY -c 'import json,sys; print(json.load(sys.stdin)["id"])') || fail "POST /runs"
for _ in $(seq 100); do
  st=$(curl -sS --max-time 10 "${URL}api/v1/runs/$rid" -H "Authorization: Bearer $(cat "$dir/sdata/token")" | $PY -c 'import json,sys; r=json.load(sys.stdin); print(r["status"], r["error"])')
  case "$st" in error*|done*|aborted*) break;; esac; sleep 0.05
done
case "$st" in "error "*"busy: modbus-tcp:127.0.0.1:$P:unit1 is in use by pid $D (command "*"fringe run"*) ;; *) fail "the service's run on a busy board: $st";; esac
set +e; wait $D; rcD=$?; set -e
[ $rcD -eq 0 ] || fail "the CLI run should pass undisturbed, got $rcD"
kill -TERM $SV; wait $SV || true

# 6c. SIGTERM while the board is frozen (retries=20 x 500 ms): the run ends within about one
#     attempt, ABORTED, the steps measured before kept.
sim frozen --modbus tcp://127.0.0.1:0 --board dut-interpolator --freeze-after 40
P=$(port_of "$SIM_AT")
"$FRINGE" run "$S" --no-db -q --device "modbus+tcp://127.0.0.1:$P?board=dut-interpolator&timeout_ms=500&retries=20" --report "$dir/term.json" > "$dir/term.log" 2>&1 &
R=$!; pids+=($R)
sleep 1
# Under the sanitizers and a loaded machine the run may still be starting a second later: wait
# until it catches SIGTERM (SigCgt bit 14 in /proc), then give it half a second of steps.
waited=0
for _ in $(seq 200); do
  mask=$(awk '/^SigCgt:/{print $2}' "/proc/$R/status" 2>/dev/null || echo 0)
  (( (0x${mask:-0} >> 14) & 1 )) && break
  waited=1; sleep 0.05
done
[ $waited -eq 0 ] || sleep 0.5
t0=$(date +%s%N); kill -TERM $R; set +e; wait $R; rc=$?; set -e; t1=$(date +%s%N)
ms=$(( (t1 - t0) / 1000000 ))
[ $ms -lt 1000 ] || fail "SIGTERM honoured ${ms} ms late"
[ $rc -eq 2 ] || fail "a terminated run exits 2, got $rc"
$PY -c 'import json,sys; r=json.load(open(sys.argv[1])); assert r["status"]=="aborted" and r["samples"]["processed"]>0, (r["status"], r["samples"], r["error"])' "$dir/term.json" \
  || fail "the terminated run: $(cat "$dir/term.log")"
echo "SIGTERM honoured in $ms ms"

# 7. Bench faults are ERRORs naming the device, not FAILs of the DUT: an ADC range (0.8 V)
#    below the signal (1.1 V), and a board whose ADC registers stop updating.
sim clip --modbus tcp://127.0.0.1:0 --board dut-interpolator --adc-range-v 0.8
P=$(port_of "$SIM_AT")
set +e
"$FRINGE" run "$S" --no-db -q --device "modbus+tcp://127.0.0.1:$P?board=dut-interpolator" --report "$dir/clip.json" > "$dir/clip.log" 2>&1; rc=$?
set -e
[ $rc -eq 2 ] || fail "a clipping board should end as ERROR (exit 2), got $rc"
grep -q "bench: clipping at the input of modbus+tcp://127.0.0.1:$P" "$dir/clip.json" || fail "clip: $(cat "$dir/clip.log")"
sim stale --modbus tcp://127.0.0.1:0 --board dut-interpolator --noise-v 2e-4 --stale-adc-after 40
P=$(port_of "$SIM_AT")
set +e
"$FRINGE" run "$S" --no-db -q --device "modbus+tcp://127.0.0.1:$P?board=dut-interpolator" --report "$dir/stale.json" > "$dir/stale.log" 2>&1; rc=$?
set -e
[ $rc -eq 2 ] || fail "a frozen board should end as ERROR (exit 2), got $rc"
grep -q "bench: the input of modbus+tcp://127.0.0.1:$P.* is frozen: 32 consecutive samples from input sample 39 " "$dir/stale.json" || fail "stale: $(cat "$dir/stale.log")"
echo "cli.modbus: ok"
