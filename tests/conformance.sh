#!/usr/bin/env bash
# Runs the driver conformance tests (tests/conformance.cpp) against one backend, setting up
# what it needs: loopback | capture | modbus-tcp | modbus-rtu | usb (emulated board, umockdev).
#   conformance.sh BACKEND FRINGE CONFORMANCE_BINARY SRC
set -euo pipefail
BACKEND="$1"; FRINGE="$2"; BIN="$3"; SRC="$(cd "$4" && pwd)"
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pids=(); CONFORMANCE_ARGS=("${@:5}")
trap 'for p in "${pids[@]}"; do kill $p 2>/dev/null || true; done; rm -rf "$dir"' EXIT
sim() {
  timeout 120 "$FRINGE" board-sim "$@" > "$dir/sim.log" 2>&1 &
  pids+=($!)
  AT=$(poll_log "$dir/sim.log" 's/.* listening on \(.*\)$/\1/p') || { cat "$dir/sim.log" >&2; exit 1; }
}
case "$BACKEND" in
  loopback) URI="loopback:?adc_bits=16&latency_samples=3&aa_cutoff_hz=45000" ;;
  capture)
    "$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/c.fcap" --samples 3000 -q
    URI="capture:$dir/c.fcap" ;;
  modbus-tcp)
    sim --modbus tcp://127.0.0.1:0 --board generic-aio
    URI="modbus+tcp://${AT#tcp://}?board=generic-aio&settle_s=0" ;;
  modbus-rtu)
    socat pty,raw,echo=0,link="$dir/ttyA" pty,raw,echo=0,link="$dir/ttyB" 2>/dev/null &
    pids+=($!)
    for _ in $(seq 100); do [ -e "$dir/ttyA" ] && [ -e "$dir/ttyB" ] && break; sleep 0.05; done
    sim --modbus "rtu:$dir/ttyA" --board dut-interpolator --unit 3 --adc-bits 0
    URI="modbus+rtu:$dir/ttyB?board=dut-interpolator&unit=3&settle_s=0" ;;
  scpi-*)
    # A generator dialect and a digitizer of fringe instrument-sim on free ports, wired by a
    # known link; a second sim that falls silent, a third that the test kills.
    case "$BACKEND" in
      scpi-keysight) GEN=keysight-33500b; DIG=generic-scope ;;
      scpi-rigol) GEN=rigol-dg1000z; DIG=generic-scope ;;
      scpi-siglent) GEN=siglent-sdg; DIG=generic-scope ;;
      scpi-redpitaya) GEN=redpitaya; DIG=redpitaya ;;
      *) echo "unknown backend $BACKEND" >&2; exit 2 ;;
    esac
    isim() {  # LOG ARGS...: starts a sim, sets GURI and DURI
      local log="$dir/$1"; shift
      "$FRINGE" instrument-sim --port 0 --generator $GEN --digitizer $DIG --exit-after 110 "$@" > "$log" 2>&1 &
      pids+=($!); LAST_PID=$!
      GURI=$(poll_log "$log" 's/^instrument-sim generator \(.*\)$/\1/p') || { cat "$log" >&2; exit 1; }
      DURI=$(poll_log "$log" 's/^instrument-sim digitizer \(.*\)$/\1/p') || { cat "$log" >&2; exit 1; }
    }
    isim main.log --delay-s 2.5e-5 --clock-ppm 40 --gain 0.9 --offset-v 0.01 --memory-samples 16384
    URI="$GURI"; export FRINGE_TEST_RECORD_URI="$DURI" FRINGE_TEST_LINK="2.5e-5 40 0.9 0.01"
    # Silent after the opening *IDN?, *CLS and SYST:ERR? (3 commands) and a little more.
    isim silent.log --silent-after 5
    export FRINGE_TEST_SILENT_URI="$GURI"
    isim gone.log
    export FRINGE_TEST_GONE_URI="$GURI" FRINGE_TEST_GONE_PID=$LAST_PID ;;
  usb)
    export LD_PRELOAD=libumockdev-preload.so.0 FRINGE_TEST_USB_EMULATOR=1
    export ASAN_OPTIONS="${ASAN_OPTIONS:-}:verify_asan_link_order=0:detect_leaks=0"
    URI="usb:1209:ec01" ;;
  *) echo "unknown backend $BACKEND" >&2; exit 2 ;;
esac
FRINGE_TEST_URI="$URI" "$BIN" "${CONFORMANCE_ARGS[@]}"
