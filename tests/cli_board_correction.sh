#!/usr/bin/env bash
# A correction written to a Modbus DUT board through the real executables, on 127.0.0.1
# (docs/modbus.md "Correction registers"): fringe run --record against board-sim with
# offsets and gain mismatch, fringe calibrate --write-board on that capture, a second
# fringe run whose DUT error has dropped; the register writes as CSV and JSON; fringe
# write-correction; a board without correction registers, a board killed mid-write and a
# table size that is not the board's exit 2 with the register or option named.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pids=()
trap 'for p in "${pids[@]}"; do kill $p 2>/dev/null || true; done; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; for f in "$dir"/*.log; do echo "== $f" >&2; cat "$f" >&2; done; exit 1; }
ok() { echo "ok - $*"; }
S="$SRC/fixtures/scenarios/modbus-step-sweep.json"
export FRINGE_LOCK_DIR="$dir/locks"

sim() {  # sim NAME ARGS...: start board-sim, set SIM_AT (tcp://127.0.0.1:PORT) from its output
  local name=$1; shift
  timeout 300 "$FRINGE" board-sim "$@" > "$dir/$name.log" 2>&1 &
  pids+=($!)
  SIM_AT=$(poll_log "$dir/$name.log" 's/.* listening on \(.*\)$/\1/p') || fail "board-sim $name did not start"
}
port_of() { echo "${1##*:}"; }
dut_rms() { $PY -c 'import json,sys; r=json.load(open(sys.argv[1])); print({e["label"]: e for e in r["estimators"]}["dut"]["metrics"]["rms"]["rad"])' "$1"; }

# 1. Before, calibrate from the recorded run and write to the board, after.
sim dut --modbus tcp://127.0.0.1:0 --board dut-interpolator --offset-sin-v 0.03 --offset-cos-v -0.02 --gain-mismatch 0.04 --noise-v 2e-4 --seed 3
URI="modbus+tcp://127.0.0.1:$(port_of "$SIM_AT")?board=dut-interpolator"
# The flaws take the board past the scenario's 0.03 rad limit (FAIL, exit 1): a verdict, not an error.
run_to() {  # run_to NAME: the step sweep against the board, recorded; exit 0 or 1 (PASS or FAIL), status done
  local rc=0
  "$FRINGE" run "$S" --no-db -q --device "$URI" --record "$dir/$1.fcap" --report "$dir/$1.json" || rc=$?
  [ $rc -le 1 ] && grep -q '"status": *"done"' "$dir/$1.json" || fail "the run $1: exit $rc"
}
run_to before
# 128 steps at 1 kHz recorded with settle_s 0: calibrate takes the capture's own settle time
# (the default 0.1 s would leave 28 steps).
out=$("$FRINGE" calibrate "$dir/before.fcap" -o "$dir/corr.json" --write-board "$URI" --modbus-writes "$dir/writes.csv") || fail "calibrate --write-board: $out"
echo "$out"
grep -qF "after 0 s settle (the capture's recording scenario)" <<<"$out" || fail "calibrate did not take the capture's settle time"
# A settle time longer than the capture: nothing scored, and the message says that, not that truth is missing.
rc=0; msg=$("$FRINGE" calibrate "$dir/before.fcap" -o "$dir/long-settle.json" --settle-s 1 2>&1) || rc=$?
[ $rc -ne 0 ] && grep -qF "nothing scored against the capture's truth" <<<"$msg" && ! grep -q "no truth" <<<"$msg" || fail "--settle-s past the end: exit $rc, $msg"
[ ! -e "$dir/long-settle.json" ] || fail "a correction was written from nothing"
grep -qF "table: 64 entries" <<<"$out" || fail "the table has the board's 64 entries"
grep -qF "wrote the correction to $URI: 72 values (72 registers), read back and verified; correction_enable = 1" <<<"$out" || fail "the write is reported"
run_to after
before=$(dut_rms "$dir/before.json"); after=$(dut_rms "$dir/after.json")
echo "DUT rms before $before rad, after $after rad"
# fringe's atan2 with the same correction on the second run's ADC readback (another capture).
"$FRINGE" estimate "$dir/after.fcap" --settle-s 0 --estimator atan2 --param "correction=$dir/corr.json" --report "$dir/sw.json" -q
$PY - "$before" "$after" "$dir/sw.json" <<'PY' || fail "the DUT's error did not drop as predicted"
import json, sys
before, after = float(sys.argv[1]), float(sys.argv[2])
e = json.load(open(sys.argv[3]))["estimators"][0]
sw, crb = e["metrics"]["rms"]["rad"], e["bounds"]["per_sample_crb_rad"]
print(f"DUT {before:.4g} -> {after:.4g} rad rms; fringe atan2 with the file on the same run {sw:.4g} (per-sample CRB {crb:.4g})")
assert before > 0.02, before
# The board applies the file as atan2 does, at its registers' quantisation (table and position
# 2*pi/65536 rad per LSB: 2.8e-5 rad rms each) and its own ADC conversions.
assert abs(after - sw) < 0.25 * sw + 5e-5, (after, sw)
assert before / after > 30, (before, after)
PY
ok "the DUT's error drops after calibrate --write-board"

# 2. The register writes as CSV: the board's values in order, enable cleared first and set last.
$PY - "$dir/writes.csv" <<'PY' || fail "the CSV register writes"
import sys
lines = open(sys.argv[1]).read().splitlines()
assert lines[0].startswith("# fringe Modbus register writes for board dut-interpolator"), lines[0]
assert lines[1] == "role,index,address,table,type,function,raw,words,value,unit", lines[1]
rows = [l.split(",") for l in lines[2:]]
assert len(rows) == 72, len(rows)
assert rows[0][:3] == ["correction_enable", "", "200"] and rows[0][6] == "0", rows[0]
assert rows[-1][:3] == ["correction_enable", "", "200"] and rows[-1][6] == "1", rows[-1]
table = [r for r in rows if r[0] == "correction_table_rad"]
assert [int(r[2]) for r in table] == list(range(256, 320))
for r in table:
    raw, word = int(r[6]), int(r[7])
    assert word == raw & 0xffff, r
    assert abs(raw * 9.587379924285257e-05 - float(r[8])) <= 9.587379924285257e-05 / 2 + 1e-12, r
PY
ok "the register writes as CSV"

# 3. write-correction: the same file as JSON for the profile alone, and to the board again.
"$FRINGE" write-correction "$dir/corr.json" --board dut-interpolator --modbus-writes "$dir/writes.json" -q
$PY -c 'import json,sys; j=json.load(open(sys.argv[1])); assert j["schema"]=="fringe.modbus_writes" and len(j["writes"])==72, j' "$dir/writes.json" \
  || fail "the JSON register writes"
"$FRINGE" write-correction "$dir/corr.json" --device "$URI" | grep -qF "read back and verified" || fail "write-correction to the board"
ok "write-correction"

# 4. Errors: exit 2, naming what is wrong.
expect_error() {  # expect_error WHAT PATTERN CMD...
  local what=$1 pat=$2; shift 2
  set +e; msg=$("$@" 2>&1); rc=$?; set -e
  [ $rc -eq 2 ] && grep -qF -- "$pat" <<<"$msg" || fail "$what: exit $rc, $msg"
  ok "$what"
}
sim aio --modbus tcp://127.0.0.1:0 --board generic-aio
expect_error "a board without correction registers" "declares no correction registers" \
  "$FRINGE" write-correction "$dir/corr.json" --device "modbus+tcp://127.0.0.1:$(port_of "$SIM_AT")?board=generic-aio"
grep -qF -- "--device" <<<"$msg" && ! grep -qF -- "--write-board" <<<"$msg" || fail "write-correction's error names calibrate's option: $msg"
expect_error "a table size that is not the board's" "--table-size" \
  "$FRINGE" calibrate "$dir/before.fcap" -o "$dir/x.json" --settle-s 0 --table-size 32 --write-board "$URI"
[ ! -e "$dir/x.json" ] || fail "a refused calibrate wrote its file"
sim drop --modbus tcp://127.0.0.1:0 --board dut-interpolator --drop-after 1
expect_error "a board killed during the table write" "write correction_table_rad[0..63] @256+64" \
  "$FRINGE" write-correction "$dir/corr.json" --device "modbus+tcp://127.0.0.1:$(port_of "$SIM_AT")?board=dut-interpolator&timeout_ms=200&retries=1"
grep -qF "correction_enable was cleared first: the board applies no correction until a write succeeds" <<<"$msg" \
  || fail "a write that failed after clearing correction_enable does not say the board is now uncorrected: $msg"
expect_error "a correction file that is not one" "correction" \
  "$FRINGE" write-correction "$dir/writes.json" --device "$URI"
