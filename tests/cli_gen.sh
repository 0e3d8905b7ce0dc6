#!/usr/bin/env bash
# fringe gen through the real executable: the paper fixture yields a 1.6 % duty-cycle error
# and a ~2.5 % second harmonic; bad input exits 2 with a message naming the problem.
set -euo pipefail
FRINGE="$1"; SRC="$2"
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }

out=$("$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/x.csv")
echo "$out"
[ -s "$dir/x.json" ] || fail "no sidecar"
[ "$(head -1 "$dir/x.csv")" = "t,sin,cos,theta_true,omega_true" ] || fail "header"
[ "$(wc -l < "$dir/x.csv")" -eq 100001 ] || fail "row count"
duty=$(echo "$out" | sed -n 's/.*duty-cycle error \([0-9.]*\) %.*/\1/p')
h2=$(echo "$out" | sed -n 's/.*h2 \([0-9.]*\) %.*/\1/p')
awk -v d="$duty" 'BEGIN{exit !(d >= 1.5 && d <= 1.7)}' || fail "duty-cycle error $duty not ~1.6 %"
awk -v h="$h2" 'BEGIN{exit !(h >= 2.4 && h <= 2.6)}' || fail "h2 $h2 not ~2.5 %"

# binary capture has the same samples
"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/x.fcap" -q --samples 1000
[ "$(stat -c %s "$dir/x.fcap")" -gt 24000 ] || fail "binary too small"

# errors: exit 2 and the key named
printf '{"name":"x","encoder":"%s","motion":{"kind":"constant","velocity_rad_s":1},"duration_s":0.01,"sampel_rate_hz":1}' \
  "$SRC/fixtures/encoders/ideal.json" > "$dir/bad.json"
set +e
msg=$("$FRINGE" gen "$dir/bad.json" -o "$dir/y.csv" 2>&1); rc=$?
set -e
[ $rc -eq 2 ] || fail "unknown key: exit $rc"
grep -q "sampel_rate_hz: unknown key" <<<"$msg" || fail "message: $msg"
echo '{"name": ' > "$dir/broken.json"
set +e; msg=$("$FRINGE" gen "$dir/broken.json" -o "$dir/y.csv" 2>&1); rc=$?; set -e
[ $rc -eq 2 ] || fail "malformed JSON: exit $rc"
grep -q "malformed JSON" <<<"$msg" || fail "message: $msg"
# seeds: 0 to 2^53, in a scenario and on the command line (not clamped, not rounded)
sed 's/"seed": 1/"seed": 9007199254740993/' "$SRC/fixtures/scenarios/paper-duty1p6.json" > "$dir/seed.json"
sed -i "s|\"\.\./encoders/|\"$SRC/fixtures/encoders/|" "$dir/seed.json"
set +e; msg=$("$FRINGE" gen "$dir/seed.json" -o "$dir/y.csv" 2>&1); rc=$?; set -e
[ $rc -eq 2 ] || fail "seed 2^53+1 in a scenario: exit $rc"
grep -q "seed: value 9007199254740993 out of range" <<<"$msg" || fail "message: $msg"
for s in 9007199254740993 18446744073709551615; do
  set +e; msg=$("$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/y.csv" --samples 10 --seed $s 2>&1); rc=$?; set -e
  [ $rc -eq 2 ] || fail "--seed $s: exit $rc"
  grep -q -- "--seed" <<<"$msg" || fail "message: $msg"
done
"$FRINGE" gen "$SRC/fixtures/scenarios/paper-duty1p6.json" -o "$dir/y.csv" --samples 10 --seed 9007199254740992 -q
grep -q '"seed": 9007199254740992' "$dir/y.json" || fail "seed 2^53 not kept exactly"
"$FRINGE" --help | grep -q gen || fail "--help"
"$FRINGE" gen --help | grep -q -- "--output" || fail "gen --help"
echo "cli_gen: all checks passed"
