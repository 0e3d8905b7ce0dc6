#!/usr/bin/env bash
# fringe calibrate through the real executable (docs/calibration.md): a correction from one
# capture of the 1.6 % duty-cycle fixture, its CSV and C header, and atan2 with it on another
# capture within 2x of the per-sample CRB; bad input exits 2 and writes nothing.
set -euo pipefail
FRINGE="$1"; SRC="$2"
PY=/usr/bin/python3
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
ok() { echo "ok - $*"; }

"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/a.fcap" -q --seed 1
"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/b.fcap" -q --seed 2
out=$("$FRINGE" calibrate "$dir/a.fcap" -o "$dir/corr.json" --csv "$dir/corr.csv" --c-header "$dir/corr.h" --name enc_corr)
echo "$out"
for want in "truth-scored error" "Lissajous: offsets" "table: 64 entries, linear interpolation" "predicted residual:" "x the per-sample CRB"; do
  grep -qF "$want" <<<"$out" || fail "summary lacks '$want'"
done
[ "$(head -1 "$dir/corr.csv")" = "angle_rad,correction_rad" ] || fail "CSV header"
[ "$(wc -l < "$dir/corr.csv")" -eq 65 ] || fail "CSV rows"
grep -q "static const int16_t enc_corr\[64\] = {" "$dir/corr.h" || fail "C header array"
# The header compiles, and its entries are the CSV's at the declared LSB.
cat > "$dir/check.c" <<'C'
#include <stdio.h>
#include "corr.h"
int main(void) { for (int i = 0; i < enc_corr_size; ++i) printf("%.17g\n", enc_corr[i] * enc_corr_lsb_rad); return 0; }
C
if command -v cc > /dev/null; then
  cc -std=c99 -Wall -Werror -o "$dir/check" "$dir/check.c" -I"$dir" || fail "the C header does not compile"
  "$dir/check" > "$dir/from_h.txt"
  $PY - "$dir/corr.csv" "$dir/from_h.txt" <<'PY' || fail "header entries differ from the CSV by more than half an LSB"
import sys, math
csv = [float(l.split(",")[1]) for l in open(sys.argv[1]).read().split("\n")[1:] if l]
h = [float(l) for l in open(sys.argv[2]) if l.strip()]
lsb = 2 * math.pi / 65536
assert len(h) == len(csv) == 64
assert all(abs(a - b) <= lsb / 2 + 1e-15 for a, b in zip(csv, h)), max(abs(a - b) for a, b in zip(csv, h))
PY
  ok "the C header compiles and holds the CSV's table at its LSB"
fi

"$FRINGE" estimate "$dir/b.fcap" --estimator atan2 --param "correction=$dir/corr.json" --report "$dir/r.json" -q
$PY - "$dir/r.json" <<'PY' || fail "atan2 with the correction on another capture is not within 2x of the CRB"
import json, sys
e = json.load(open(sys.argv[1]))["estimators"][0]
rms, crb = e["metrics"]["rms"]["rad"], e["bounds"]["per_sample_crb_rad"]
print(f"atan2 corrected on another capture: {rms:.4g} rad rms, {rms / crb:.3f} x the per-sample CRB")
assert rms < 2 * crb
PY
ok "verified on another capture"

# The self-referenced error chosen with truth at hand (what a bench without a reference encoder gets).
out=$("$FRINGE" calibrate "$dir/a.fcap" -o "$dir/corr-sr.json" --error-source self-reference)
grep -qF "(self-referenced error)" <<<"$out" || fail "--error-source self-reference: $out"
grep -q '"error_source": "self_reference"' "$dir/corr-sr.json" || fail "the file does not say self_reference"
set +e; msg=$("$FRINGE" calibrate "$dir/a.fcap" -o "$dir/x.json" --error-source reference 2>&1); rc=$?; set -e
[ $rc -ne 0 ] && [ ! -e "$dir/x.json" ] || fail "--error-source reference: exit $rc, $msg"
ok "--error-source chooses the error record"

# Bad input exits 2 and writes nothing: an LSB at which the table does not fit int16.
set +e; msg=$("$FRINGE" calibrate "$dir/a.fcap" -o "$dir/x.json" --c-header "$dir/x.h" --lsb-rad 1e-7 2>&1); rc=$?; set -e
[ $rc -eq 2 ] && grep -q "does not fit int16" <<<"$msg" || fail "int16 overflow: exit $rc, $msg"
[ ! -e "$dir/x.json" ] && [ ! -e "$dir/x.h" ] || fail "files written despite the error"
ok "an entry that does not fit int16 is refused, nothing written"
set +e; msg=$("$FRINGE" calibrate "$dir/a.fcap" -o "$dir/a.fcap" 2>&1); rc=$?; set -e
[ $rc -eq 2 ] || fail "overwriting the capture: exit $rc, $msg"
set +e; msg=$("$FRINGE" calibrate "$dir/a.fcap" -o "$dir/y.json" --estimator pll2 2>&1); rc=$?; set -e
[ $rc -eq 2 ] && grep -q "only atan2" <<<"$msg" || fail "pll2: exit $rc, $msg"
ok "the capture is not overwritten; an estimator it cannot calibrate is named"

# Found by a hostile trial: an LSB coarser than the whole correction (a header of zeros), a C
# array name that is not an identifier (pasted into C source), an output over a CSV capture's
# sidecar (the capture became unreadable), a correction file with values no error can have.
set +e; msg=$("$FRINGE" calibrate "$dir/a.fcap" -o "$dir/x.json" --c-header "$dir/x.h" --lsb-rad 1 2>&1); rc=$?; set -e
[ $rc -eq 2 ] && grep -q "every entry would round to 0" <<<"$msg" || fail "--lsb-rad 1: exit $rc, $msg"
[ ! -e "$dir/x.json" ] && [ ! -e "$dir/x.h" ] || fail "files written despite the coarse LSB"
for name in "x y" "1abc" "int" 'x[1];int y' '*/' ""; do
  set +e; msg=$("$FRINGE" calibrate "$dir/a.fcap" -o "$dir/x.json" --c-header "$dir/x.h" --name "$name" 2>&1); rc=$?; set -e
  [ $rc -ne 0 ] && grep -qi "identifier\|keyword" <<<"$msg" || fail "--name '$name': exit $rc, $msg"
  [ ! -e "$dir/x.h" ] || fail "--name '$name' wrote a header"
done
"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/c.csv" -q --seed 3
cp "$dir/c.json" "$dir/c.json.orig"
for opt in "-o $dir/c.json" "-o $dir/y.json --csv $dir/c.json"; do
  set +e; msg=$("$FRINGE" calibrate "$dir/c.csv" $opt 2>&1); rc=$?; set -e
  [ $rc -eq 2 ] && grep -q "sidecar" <<<"$msg" || fail "calibrate $opt over the sidecar: exit $rc, $msg"
  cmp -s "$dir/c.json" "$dir/c.json.orig" || fail "the sidecar was changed by calibrate $opt"
done
$PY - "$dir/corr.json" "$dir" <<'PY' || fail "writing the damaged corrections"
import json, sys
c = json.load(open(sys.argv[1]))
for name, key, value in [("big-offset", "offset_rad", 1e308), ("big-entry", "table_rad", None)]:
    d = json.loads(json.dumps(c))
    if value is None:
        d["table_rad"][3] = 1e300
    else:
        d[key] = value
    json.dump(d, open(f"{sys.argv[2]}/{name}.json", "w"))
PY
for bad in big-offset big-entry; do
  set +e; msg=$("$FRINGE" estimate "$dir/b.fcap" --estimator atan2 --param "correction=$dir/$bad.json" --report "$dir/bad.rep.json" -q 2>&1); rc=$?; set -e
  [ $rc -eq 2 ] && grep -q "correction\.\(offset_rad\|table_rad\[3\]\)" <<<"$msg" || fail "$bad: exit $rc, $msg"
done
mkfifo "$dir/fifo.json"
set +e; msg=$(timeout 20 "$FRINGE" estimate "$dir/b.fcap" --estimator atan2 --param "correction=$dir/fifo.json" --report "$dir/bad.rep.json" -q 2>&1); rc=$?; set -e
[ $rc -eq 2 ] && grep -q "not a regular file" <<<"$msg" || fail "a FIFO as the correction: exit $rc, $msg"
ok "hostile exports and correction files are refused, nothing written or changed"
