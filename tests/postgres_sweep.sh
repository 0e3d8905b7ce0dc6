#!/usr/bin/env bash
# The Table 1 sweep sharded over a shared PostgreSQL store (a throwaway PostgreSQL 15 started
# here): shards 0 and 1 of 3 at once under GNU parallel (each with its own spool folder, as on
# separate hosts), shard 0 run twice (the second run stores nothing new), shard 2 killed
# halfway; --collect names the missing rows, --collect --only-missing runs them; the table
# collected from the store equals the single-process sweep row for row (every column but the
# wall time). Fixture: Table 1's 23 rows with duration_s set by the third argument (2 s in a
# Release build, so that a row takes long enough to kill a shard between rows; 0.1 s under
# the sanitizers, which are ~250x slower). Rows, estimators and sharding are Table 1's.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"; DURATION_S="${3:-2}"
PY=/usr/bin/python3
. "$SRC/tests/pg_lib.sh"
dir=$(mktemp -d); spid=
trap 'kill -9 $spid 2>/dev/null || true; pg_halt "$dir"; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
command -v parallel > /dev/null || fail "GNU parallel is not installed (Debian package parallel; scripts/setup --test installs it)"
pg_start "$dir" || exit 1

T="$dir/table1.json"
$PY - "$SRC/fixtures/sweeps/table1.json" "$T" "$DURATION_S" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["base"]["duration_s"] = float(sys.argv[3])
json.dump(s, open(sys.argv[2], "w"))
PY
rows=$($PY -c 'import json,sys; print(len(json.load(open(sys.argv[1]))["rows"]))' "$T")
sweep_runs() { pg_sql "SELECT COUNT(*) FROM runs WHERE id LIKE 'sweep-%'"; }

"$FRINGE" sweep "$T" --csv "$dir/single.csv" --md "$dir/single.md" -q || fail "single-process sweep"

# Shards 0 and 1 at once, as two hosts would run them.
parallel --will-cite -q --halt now,fail=1 -j2 "$FRINGE" sweep "$T" --store "$PGURI" --data "$dir/host{}" --shard {}/3 --jobs 1 -q ::: 0 1 \
  || fail "shards 0 and 1 under GNU parallel"
n01=$(sweep_runs)
expect=$(( (rows + 2) / 3 + (rows + 1) / 3 ))
[ "$n01" = "$expect" ] || fail "shards 0 and 1 stored $n01 rows, expected $expect"
# Shard 0 again (a retried array task): nothing new.
stamp=$(pg_sql "SELECT string_agg(id || stored_at, ',' ORDER BY id) FROM runs")
"$FRINGE" sweep "$T" --store "$PGURI" --data "$dir/host0b" --shard 0/3 2> "$dir/again.txt" > /dev/null || fail "shard 0 again"
grep -q "already stored, running 0" "$dir/again.txt" || fail "a retried shard runs nothing: $(cat "$dir/again.txt")"
[ "$(pg_sql "SELECT string_agg(id || stored_at, ',' ORDER BY id) FROM runs")" = "$stamp" ] || fail "a retried shard changed the store"

# Shard 2 killed halfway (kill -9 after its first rows are in the store).
"$FRINGE" sweep "$T" --store "$PGURI" --data "$dir/host2" --shard 2/3 --jobs 1 -q > /dev/null 2>&1 & spid=$!
for _ in $(seq 1200); do [ "$(sweep_runs)" -ge $((n01 + 2)) ] && break; sleep 0.05; done
kill -9 $spid; wait $spid 2>/dev/null || true; spid=
have=$(sweep_runs)
echo "shard 2 killed with $have of $rows rows in the store"
[ "$have" -ge $((n01 + 2)) ] && [ "$have" -lt "$rows" ] || fail "shard 2 should be killed halfway ($have of $rows rows stored)"

set +e
"$FRINGE" sweep "$T" --collect --store "$PGURI" --csv "$dir/partial.csv" -q 2> "$dir/missing.txt"; rc=$?
set -e
[ $rc -eq 2 ] || fail "--collect with rows missing exits 2, got $rc"
grep -q "$((rows - have)) of $rows rows are missing" "$dir/missing.txt" || fail "names how many are missing: $(cat "$dir/missing.txt")"
[ "$(grep -c '^  row ' "$dir/missing.txt")" = $((rows - have)) ] || fail "names each missing row: $(cat "$dir/missing.txt")"

"$FRINGE" sweep "$T" --collect --only-missing --store "$PGURI" --data "$dir/collector" --csv "$dir/c.csv" --md "$dir/c.md" -q \
  || fail "--collect --only-missing"
[ "$(sweep_runs)" = "$rows" ] || fail "every row is stored once"
[ "$(pg_sql "SELECT COUNT(*) FROM run_conflicts")" = 0 ] || fail "no conflicts"
cmp "$dir/single.md" "$dir/c.md" || fail "the collected Markdown table differs: $(diff "$dir/single.md" "$dir/c.md")"
$PY - "$dir/single.csv" "$dir/c.csv" <<'PY' || fail "the collected CSV differs"
import csv, sys
a, b = (list(csv.DictReader(open(p))) for p in sys.argv[1:3])
assert len(a) == len(b) == 23, (len(a), len(b))
for x, y in zip(a, b):
    x.pop("wall_s"); y.pop("wall_s")
    assert x == y, (x, y)
PY
echo "postgres.sweep OK"
