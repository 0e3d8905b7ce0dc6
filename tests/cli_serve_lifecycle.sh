#!/usr/bin/env bash
# fringe serve's lifecycle and resource limits through the real executable on 127.0.0.1:
# one service per data folder (the second exits 2 naming the holder); a run killed with its
# service is interrupted at the next start even when a live process has its old PID, and its
# event stream ends; a run's status comes from its stored summary, not its report; a `fringe run --data` beside the service stays running and is
# interrupted once killed; files are 0600; a full disk answers 507; with no file
# descriptors left the accept loop backs off instead of spinning, and recovers.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pid=; pid2=; clipid=; mnt=
cleanup() {
  for p in $pid $pid2 $clipid; do kill -9 "$p" 2>/dev/null || true; done
  [ -n "$mnt" ] && umount "$mnt" 2>/dev/null || true
  rm -rf "$dir"
}
trap cleanup EXIT
fail() { echo "FAIL: $*" >&2; for f in "$dir"/*.log; do [ -s "$f" ] && { echo "== $f" >&2; tail -20 "$f" >&2; }; done; exit 1; }

start() {  # start DATA [extra args...]: a server on a free port; sets pid and URL
  local data=$1; shift
  : > "$dir/serve.log"
  "$FRINGE" serve --bind 127.0.0.1:0 --data "$data" "$@" > "$dir/serve.out" 2> "$dir/serve.log" &
  pid=$!
  URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 200 0.1) || fail "fringe serve did not start"
}
api() { curl -sS --max-time 10 "$@"; }
status_of() { api "${URL}api/v1/runs/$1" | $PY -c 'import json,sys; r=json.load(sys.stdin); print(r["status"], r["verdict"] or "")'; }
post_run() { api -X POST -H "Authorization: Bearer $(cat "$D/token")" -d "{\"fixture\":\"$1\"}" "${URL}api/v1/runs" | $PY -c 'import json,sys; print(json.load(sys.stdin)["id"])'; }
wait_status() {  # wait_status ID "STATUS VERDICT" [TRIES, 0.05 s apart]
  for _ in $(seq "${3:-200}"); do [ "$(status_of "$1")" = "$2" ] && return 0; sleep 0.05; done
  return 1
}

D="$dir/data"
start "$D"

# --- one service per data folder
set +e
"$FRINGE" serve --bind 127.0.0.1:0 --data "$D" > "$dir/second.out" 2> "$dir/second.log" &
pid2=$!
for _ in $(seq 100); do kill -0 $pid2 2>/dev/null || break; sleep 0.05; done
kill -0 $pid2 2>/dev/null && fail "a second fringe serve on the same data folder is running"
wait $pid2; rc=$?; pid2=
set -e
[ $rc -eq 2 ] || fail "second serve on one folder: exit 2 expected, got $rc"
grep -q "$D" "$dir/second.log" && grep -q "pid $pid " "$dir/second.log" && grep -q "instance" "$dir/second.log" \
  || fail "second serve names the folder and the holder's pid: $(cat "$dir/second.log")"

# --- file modes: the run store (and its WAL) and uploads are private like the token
id=$(post_run fig10c-loopback)
wait_status "$id" "done PASS" 2400 || fail "fig10c did not finish: $(status_of "$id")"
$PY - "$dir/cap.csv" <<'PY'
import math, sys
with open(sys.argv[1], "w") as f:
    f.write("t,sin,cos\n")
    for i in range(2000):
        t = i / 20000.0; th = 2 * math.pi * 50 * t
        f.write(f"{t:.8f},{math.sin(th):.6f},{math.cos(th):.6f}\n")
PY
api -X POST -H "Authorization: Bearer $(cat "$D/token")" --data-binary @"$dir/cap.csv" "${URL}api/v1/captures" > "$dir/up.json"
cid=$($PY -c 'import json,sys; print(json.load(open(sys.argv[1]))["id"])' "$dir/up.json") || fail "upload: $(cat "$dir/up.json")"
for f in "$D/runs.db" "$D/runs.db-wal" "$D/captures/$cid.csv" "$D/captures/$cid.upload.json"; do
  [ -e "$f" ] || fail "$f missing"
  [ "$(stat -c %a "$f")" = 600 ] || fail "$f has mode $(stat -c %a "$f"), expected 600"
done

# --- kill -9 mid-run; a live process then has the old PID; restart: interrupted, stream ends
id2=$(post_run perf-1e7)
wait_status "$id2" "running " || fail "perf-1e7 did not start"
kill -9 $pid; wait $pid 2>/dev/null || true
# The dead service's PID, as a restarted container's PID 1 or a reused PID would be: alive.
sleep 300 & holder=$!
# And the finished run's stored report made unreadable: a status query must not parse it (it
# used to, under the store lock, for every GET runs/{id} and every event stream poll).
$PY - "$D/runs.db" "$id2" "$holder" "$id" <<'PY'
import sqlite3, sys
db = sqlite3.connect(sys.argv[1])
db.execute("UPDATE runs SET pid = ? WHERE id = ?", (int(sys.argv[3]), sys.argv[2]))
db.execute("UPDATE runs SET report = '{\"not json' WHERE id = ?", (sys.argv[4],))
db.commit()
PY
start "$D"
api "${URL}api/v1/runs/$id" | $PY -c '
import json,sys; r=json.load(sys.stdin)
assert r["status"] == "done" and r["verdict"] == "PASS" and r["progress"]["done"] == r["progress"]["total"] == 100000, r
assert r["device"].startswith("loopback:"), r["device"]' || fail "GET runs/{id} from the stored summary"
st=$(status_of "$id2")
kill $holder 2>/dev/null || true
[ "$st" = "interrupted ABORTED" ] || fail "a killed service's run must be interrupted at restart whatever its PID, is '$st'"
curl -sS --max-time 5 "${URL}api/v1/runs/$id2/events" > "$dir/events.txt" || true
grep -q "event: end" "$dir/events.txt" || fail "the interrupted run's event stream ends: $(head -c 300 "$dir/events.txt")"
code=$(api -o /dev/null -w '%{http_code}' -X POST -H "Authorization: Bearer $(cat "$D/token")" "${URL}api/v1/runs/$id2/cancel")
[ "$code" = 409 ] || fail "cancel of an interrupted run: 409, got $code"

# --- a CLI run on the same folder, started before a service restart: it stays running
kill -TERM $pid; wait $pid || true
$PY - "$SRC/fixtures/scenarios/perf-1e7.json" "$dir/long.json" <<'PY'
import json, os, sys
sc = json.load(open(sys.argv[1]))
sc["encoder"] = os.path.normpath(os.path.join(os.path.dirname(sys.argv[1]), sc["encoder"]))
sc["duration_s"] = 2000.0  # killed long before its end
json.dump(sc, open(sys.argv[2], "w"))
PY
"$FRINGE" run "$dir/long.json" --data "$D" -q > "$dir/cli.out" 2> "$dir/cli.log" &
clipid=$!
cli_id=
for _ in $(seq 200); do
  cli_id=$($PY - "$D/runs.db" <<'PY'
import sqlite3, sys
r = sqlite3.connect(sys.argv[1]).execute("SELECT id FROM runs WHERE status = 'running' AND instance LIKE 'cli-%'").fetchone()
print(r[0] if r else "")
PY
)
  [ -n "$cli_id" ] && break; sleep 0.05
done
[ -n "$cli_id" ] || fail "the CLI run is not in the store"
start "$D"
[ "$(status_of "$cli_id")" = "running " ] || fail "a CLI run beside the service must stay running, is $(status_of "$cli_id")"
kill -9 $clipid; wait $clipid 2>/dev/null || true; clipid=
[ "$(status_of "$cli_id")" = "interrupted ABORTED" ] || fail "a killed CLI run is interrupted, is $(status_of "$cli_id")"
kill -TERM $pid; wait $pid || true

# --- file descriptors exhausted: back off, do not spin; recover when they are free
E="$dir/emfile"
prlimit --nofile=48:48 "$FRINGE" serve --bind 127.0.0.1:0 --data "$E" --max-connections 1000 > "$dir/serve.out" 2> "$dir/serve.log" &
pid=$!
URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 200 0.1) || fail "fringe serve (48 fds) did not start"
$PY - "$URL" "$pid" <<'PY' || fail "EMFILE"
import os, socket, sys, time, urllib.parse, urllib.request
u = urllib.parse.urlparse(sys.argv[1]); pid = int(sys.argv[2])
tick = os.sysconf("SC_CLK_TCK")
def cpu_s():
    f = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / tick
conns = []
for _ in range(80):  # more than the server has descriptors for
    s = socket.create_connection((u.hostname, u.port)); conns.append(s)
time.sleep(0.5)
c0 = cpu_s(); time.sleep(2.0); used = cpu_s() - c0
print(f"server CPU with descriptors exhausted: {used:.2f} s in 2 s")
assert used < 0.5, f"the accept loop spins: {used:.2f} s of CPU in 2 s"
for s in conns: s.close()
deadline = time.time() + 10
while True:
    try:
        assert urllib.request.urlopen(sys.argv[1] + "api/v1/health", timeout=2).status == 200
        break
    except Exception as e:
        if time.time() > deadline: raise AssertionError(f"no recovery: {e!r}")
        time.sleep(0.1)
PY
grep -q "accept: .*retrying" "$dir/serve.log" || fail "the accept failure is logged"
kill -TERM $pid; wait $pid || true

# --- disk full: an upload gets 507 JSON, the partial file is removed, the service goes on
F="$dir/full"; mkdir -p "$F"
how=
if mount -t tmpfs -o size=2m tmpfs "$F" 2>/dev/null; then
  mnt=$F; how="a 2 MiB tmpfs"
  start "$F"
else  # not root: a file size limit gives EFBIG on the upload's write instead of ENOSPC
  how="RLIMIT_FSIZE 1 MiB"
  : > "$dir/serve.log"
  (trap '' XFSZ; ulimit -f 1024; exec "$FRINGE" serve --bind 127.0.0.1:0 --data "$F") > "$dir/serve.out" 2> "$dir/serve.log" &
  pid=$!
  URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 200 0.1) || fail "fringe serve did not start"
fi
head -c 4000000 /dev/urandom > "$dir/big.bin"
code=$(curl -sS --max-time 20 -o "$dir/full.json" -w '%{http_code}' -X POST -H "Authorization: Bearer $(cat "$F/token")" \
  --data-binary @"$dir/big.bin" "${URL}api/v1/captures") || true
[ "$code" = 507 ] && grep -q '"storage_full"' "$dir/full.json" || fail "disk full ($how): 507 storage_full expected, got '$code' $(cat "$dir/full.json" 2>/dev/null)"
ls -a "$F/captures" | grep -q '^\.upload' && fail "the partial upload is left on the full disk"
api -X POST -H "Authorization: Bearer $(cat "$F/token")" --data-binary @"$dir/cap.csv" -o /dev/null -w '%{http_code}' "${URL}api/v1/captures" \
  | grep -q 201 || fail "a small upload after the full one"
kill -TERM $pid; wait $pid || true; pid=
echo "disk full tested with $how"
echo "cli.serve_lifecycle: ok"
