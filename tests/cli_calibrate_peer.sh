#!/usr/bin/env bash
# fringe calibrate against an independent implementation (Debian's numpy): on a record of 1.3
# electrical cycles of the paper's 1.6 % duty-cycle signal (angles visited unevenly), numpy
#   1. applies fringe's correction file to another capture as docs/calibration.md states it
#      (Lissajous stage, atan2, theta = phi - offset_rad - table(phi), linear between entries
#      with the wrap) and must measure what `fringe estimate` measures with it;
#   2. computes its own correction by least squares over the same record (constant and 16
#      harmonics against the truth, inverted to the angle read) and must leave the same residual
#      on the other capture as fringe's.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
"$PY" -c "import numpy" || { echo "FAIL: Debian's python3-numpy is missing (scripts/setup --tests installs it)" >&2; exit 1; }
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
"$PY" - "$SRC" "$dir" <<'PY'
import json, sys
s = json.load(open(f"{sys.argv[1]}/fixtures/scenarios/paper-duty1p6.json"))
s["encoder"] = f"{sys.argv[1]}/fixtures/encoders/paper-d2-duty1p6.json"
s["duration_s"] = 0.1 + 1.3 / s["motion"]["electrical_freq_hz"]
json.dump(s, open(f"{sys.argv[2]}/short.json", "w"))
PY
"$FRINGE" gen "$dir/short.json" -o "$dir/a.csv" -q --seed 4
"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/b.csv" -q --seed 5
"$FRINGE" calibrate "$dir/a.csv" -o "$dir/corr.json" -q
"$FRINGE" estimate "$dir/b.csv" --estimator atan2 --param "correction=$dir/corr.json" --report "$dir/r.json" -q
"$PY" - "$dir" <<'PY' || fail "numpy disagrees with fringe"
import json, sys
import numpy as np
d = sys.argv[1]
c = json.load(open(f"{d}/corr.json"))
L = c["lissajous"]
settle_s = 0.1
def reading(path):
    x = np.loadtxt(path, delimiter=",", skiprows=1)
    t, s, co, th = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    sn = (s - L["offset_sin_v"]) / L["amplitude_sin_v"]
    cn = ((co - L["offset_cos_v"]) / L["amplitude_cos_v"] + sn * np.sin(L["quadrature_error_rad"])) / np.cos(L["quadrature_error_rad"])
    phi = np.arctan2(sn, cn)
    keep = t - t[0] >= settle_s
    return phi[keep], th[keep]
wrap = lambda x: np.angle(np.exp(1j * x))
# 1. fringe's file, applied by numpy, on the other capture
tab = np.array(c["table_rad"]); n = len(tab)
def table(p):
    x = np.mod(p, 2 * np.pi) * n / (2 * np.pi)
    i = np.floor(x).astype(int) % n
    f = x - np.floor(x)
    return tab[i] + f * (tab[(i + 1) % n] - tab[i])
phi_b, th_b = reading(f"{d}/b.csv")
e_file = wrap(phi_b - c["offset_rad"] - table(phi_b) - th_b)
rms_file = np.sqrt(np.mean(e_file ** 2))
rep = json.load(open(f"{d}/r.json"))["estimators"][0]["metrics"]
rms_fringe = rep["rms"]["rad"]
print(f"fringe's file on the other capture: numpy {rms_file:.5g} rad rms, fringe estimate {rms_fringe:.5g}")
assert abs(rms_file - rms_fringe) < 1e-3 * rms_fringe, (rms_file, rms_fringe)
# 2. numpy's own correction from the same record
phi_a, th_a = reading(f"{d}/a.csv")
K = 16
def design(a):
    cols = [np.ones_like(a)]
    for k in range(1, K + 1):
        cols += [np.cos(k * a), np.sin(k * a)]
    return np.stack(cols, 1)
coef, *_ = np.linalg.lstsq(design(th_a), wrap(phi_a - th_a), rcond=None)
def corr(p):  # e(s(phi)), s solved from phi = s + e(s)
    s = p.copy()
    for _ in range(30):
        s = p - design(s) @ coef
    return design(s) @ coef
e_own = wrap(phi_b - corr(phi_b) - th_b)
rms_own = np.sqrt(np.mean(e_own ** 2))
print(f"numpy's own correction from the same 1.3-cycle record: {rms_own:.5g} rad rms on the other capture")
# fringe's table interpolates linearly between 64 entries; numpy uses the harmonics themselves
assert rms_fringe < 1.15 * rms_own, (rms_fringe, rms_own)
PY
echo "ok - fringe calibrate agrees with a numpy least-squares correction"
