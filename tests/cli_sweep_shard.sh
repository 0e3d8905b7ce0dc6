#!/usr/bin/env bash
# Sharded sweeps on the default SQLite store, as docs/scale.md promises: with neither --store
# nor --data, --shard and --collect use $FRINGE_DATA/runs.db; --collect names the missing row
# and exits 2; --only-missing runs it; a shard given by SLURM_ARRAY_TASK_ID lands in the store.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
/usr/bin/python3 - "$SRC/fixtures/scenarios/fig10c-loopback.json" "$dir/sw.json" <<'PY'
import json, sys
b = json.load(open(sys.argv[1]))
b.update(duration_s=0.3, estimators=[{"name": "atan2"}], limits=[])
b["encoder"] = {"model": "ideal", "lines_per_rev": 1024, "vmax_v": 1.0, "noise": {"sigma_add_v": 2e-4}}
json.dump({"name": "tiny", "base": b, "grid": {"seed": [1, 2, 3]}, "columns": [{"estimator": "atan2", "metric": "rms_rad"}]}, open(sys.argv[2], "w"))
PY
export FRINGE_DATA="$dir/data"
"$FRINGE" sweep "$dir/sw.json" --shard 0/3 -q || fail "--shard on the default store"
SLURM_ARRAY_TASK_ID=1 SLURM_ARRAY_TASK_COUNT=3 "$FRINGE" sweep "$dir/sw.json" -q || fail "a Slurm array task on the default store"
set +e; "$FRINGE" sweep "$dir/sw.json" --collect --md "$dir/partial.md" > "$dir/c.txt" 2>&1; rc=$?; set -e
[ $rc -eq 2 ] || fail "--collect with a row missing should exit 2, got $rc"
grep -q "seed=3 (MISSING" "$dir/c.txt" || fail "--collect names the missing row: $(cat "$dir/c.txt")"
grep -q "seed=1 | [0-9]" "$dir/c.txt" && grep -q "seed=2 | [0-9]" "$dir/c.txt" || fail "shards 0 and 1 collected: $(cat "$dir/c.txt")"
"$FRINGE" sweep "$dir/sw.json" --collect --only-missing --md "$dir/all.md" -q || fail "--only-missing"
"$FRINGE" sweep "$dir/sw.json" --md "$dir/single.md" -q
cmp -s "$dir/all.md" "$dir/single.md" || fail "collected table differs from the single-process one: $(diff "$dir/all.md" "$dir/single.md")"
echo "sharded sweep on the default store: ok"
