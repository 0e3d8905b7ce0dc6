#!/usr/bin/env bash
# The README's first run, as a new user copies it: the scenario JSON under "A first run" runs
# with the real fringe, PASSes (exit 0) and prints the summary lines the README shows.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
dir=$(mktemp -d); trap 'rm -rf "$dir"' EXIT
/usr/bin/python3 - "$SRC/README.md" "$dir/my-board.json" <<'PY'
import re, sys
s = open(sys.argv[1], encoding="utf-8").read()
sec = s[s.index("## A first run"):]
sec = sec[:sec.index("\n## ", 1)]
m = re.search(r"```json\n(.*?)```", sec, re.S)
assert m, "no JSON scenario in the README's first run"
open(sys.argv[2], "w").write(m.group(1))
PY
cd "$dir"
"$FRINGE" run my-board.json --data "$dir/data" --html my-board.html > out.txt || { cat out.txt; echo "FAIL: the README's first run did not PASS"; exit 1; }
grep -q "my-board PASS (done)" out.txt || { cat out.txt; echo "FAIL: verdict line"; exit 1; }
grep -q "PASS     atan2 rms_rad = .* rad (95 % .*) (limit <= 0.001)" out.txt || { cat out.txt; echo "FAIL: the limit line the README shows"; exit 1; }
grep -q "samples per electrical cycle" out.txt || { cat out.txt; echo "FAIL: the preflight warning the README explains"; exit 1; }
grep -qi "<html" my-board.html || { echo "FAIL: --html"; exit 1; }
id=$("$FRINGE" runs --data "$dir/data" --json | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)[0]["id"])')
"$FRINGE" runs --data "$dir/data" --show "$id" | grep -q "my-board PASS" || { echo "FAIL: runs --show"; exit 1; }
echo "the README's first run: PASS"
