#!/usr/bin/env bash
# A `fringe run` killed with SIGKILL leaves its row "running" in DATA/runs.db and its
# DATA/locks/cli-*.lock behind. The next command that opens the folder (here `fringe runs`, then
# `fringe run`) recognises the owner is gone (nobody holds its lock), marks the row interrupted
# in the database for good and removes the lock file; a run that is alive is left alone.
# Five kills in a loop, each bounded (the run is killed as soon as its row is "running").
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
dir=$(mktemp -d); pid=
trap 'kill -9 $pid 2>/dev/null || true; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
command -v sqlite3 > /dev/null || fail "the sqlite3 command is not installed (Debian package sqlite3; scripts/setup --test installs it)"
D="$dir/data"
$PY - "$SRC/fixtures/scenarios/fig10c-loopback.json" "$dir/long.json" "$dir/short.json" <<'PY'
import json, sys
b = json.load(open(sys.argv[1]))
b.update(estimators=[{"name": "atan2"}], limits=[])
b["encoder"] = {"model": "ideal", "lines_per_rev": 1024, "vmax_v": 1.0, "noise": {"sigma_add_v": 2e-4}}
b["duration_s"] = 600  # minutes of work: it is killed long before it ends
json.dump(b, open(sys.argv[2], "w"))
b["duration_s"] = 0.2
json.dump(b, open(sys.argv[3], "w"))
PY
q() { sqlite3 "$D/runs.db" "$1"; }
locks() { find "$D/locks" -name 'cli-*.lock' 2>/dev/null | wc -l; }
# Starts the long run in the background and waits (up to 20 s) until its row is "running".
start_long() {
  "$FRINGE" run "$dir/long.json" --data "$D" -q > "$dir/run.log" 2>&1 & pid=$!
  for _ in $(seq 400); do
    [ -f "$D/runs.db" ] && [ "$(q "SELECT COUNT(*) FROM runs WHERE status = 'running'" 2>/dev/null || echo 0)" = 1 ] && return 0
    kill -0 $pid 2>/dev/null || fail "the run ended early: $(cat "$dir/run.log")"
    sleep 0.05
  done
  fail "no running row after 20 s"
}

for i in 1 2 3 4 5; do
  start_long
  id=$(q "SELECT id FROM runs WHERE status = 'running'")
  [ "$(locks)" = 1 ] || fail "iteration $i: the live run holds one lock file, found $(locks)"
  # A live run is not taken for dead by another command on the folder.
  "$FRINGE" runs --data "$D" > /dev/null
  [ "$(q "SELECT status FROM runs WHERE id = '$id'")" = running ] || fail "iteration $i: a live run was marked $(q "SELECT status FROM runs WHERE id = '$id'")"
  [ "$(locks)" = 1 ] || fail "iteration $i: a live run's lock file was removed"
  kill -9 $pid; wait $pid 2>/dev/null || true; pid=
  [ "$(locks)" = 1 ] || fail "iteration $i: expected the killed run's lock file to be left behind"
  # The next command that opens the folder settles it.
  "$FRINGE" runs --data "$D" > "$dir/runs.txt" 2> "$dir/runs.err"
  st=$(q "SELECT status || ' ' || COALESCE(verdict, '') FROM runs WHERE id = '$id'")
  [ "$st" = "interrupted ABORTED" ] || fail "iteration $i: the killed run's row is '$st' in runs.db after the next command, expected 'interrupted ABORTED'"
  [ "$(locks)" = 0 ] || fail "iteration $i: $(locks) lock file(s) left in $D/locks after the next command: $(ls "$D/locks")"
  grep -q "marked interrupted" "$dir/runs.err" || fail "iteration $i: the next command says what it did: $(cat "$dir/runs.err")"
done
[ "$(q "SELECT COUNT(*) FROM runs WHERE status = 'interrupted'")" = 5 ] || fail "five interrupted rows"

# The next command may also be a run: it settles the killed one before its own.
start_long
id=$(q "SELECT id FROM runs WHERE status = 'running'")
kill -9 $pid; wait $pid 2>/dev/null || true; pid=
"$FRINGE" run "$dir/short.json" --data "$D" -q > /dev/null 2>&1 || true
[ "$(q "SELECT status FROM runs WHERE id = '$id'")" = interrupted ] || fail "fringe run did not settle the killed run"
[ "$(locks)" = 0 ] || fail "lock files left after fringe run: $(ls "$D/locks")"
echo "killed runs settled by the next command: ok"
