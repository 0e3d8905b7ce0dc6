#!/usr/bin/env bash
# Uploads that claim more than they hold, through the real executable on 127.0.0.1: a 1 MB
# sigrok ZIP bomb (two members of 512 MiB of zeros) is refused with 413 naming
# --max-upload-expanded-mb before anything is inflated; one whose headers lie about its sizes
# is refused as it inflates; one within the limit (128 MiB of samples from 130 KB) is validated
# block by block. Throughout, the service's peak resident memory (VmHWM) stays within 64 MiB
# of its idle resident memory and /api/v1/health answers. The upload quota counts expanded
# sizes; a .fcap whose header nests 10^6 levels deep is refused naming the depth (upload and
# `fringe estimate`), and `fringe estimate` on the bomb exits 2 naming its limit.
set -euo pipefail
FRINGE="$1"; SRC="$(cd "$2" && pwd)"
PY=/usr/bin/python3
. "$SRC/tests/lib.sh"
dir=$(mktemp -d); pid=
trap 'kill -9 $pid 2>/dev/null || true; rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*" >&2; [ -f "$dir/serve.log" ] && tail -n 20 "$dir/serve.log" >&2; exit 1; }
BOUND_KIB=$((64 * 1024))  # peak resident memory over idle, at most

start() {  # start the server on a free port (extra serve options as arguments); sets pid and URL
  : > "$dir/serve.log"
  "$FRINGE" serve --bind 127.0.0.1:0 --data "$dir/data" "$@" > "$dir/serve.out" 2> "$dir/serve.log" &
  pid=$!
  URL=$(poll_log "$dir/serve.out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 200 0.1) || fail "fringe serve did not start"
  TOKEN=$(cat "$dir/data/token")
}
stop() { kill -TERM $pid; wait $pid || true; pid=; }

# The captures (generated here, not kept in the repository).
timeout 120 $PY "$SRC/tests/zip_bomb.py" "$dir/bomb.sr" --mib 512
timeout 120 $PY "$SRC/tests/zip_bomb.py" "$dir/lie.sr" --mib 512 --declare-mib 4
timeout 120 $PY "$SRC/tests/zip_bomb.py" "$dir/ok.sr" --mib 64
for f in bomb lie ok; do echo "$f.sr: $(stat -c %s "$dir/$f.sr") bytes"; done
[ "$(stat -c %s "$dir/bomb.sr")" -lt 1200000 ] || fail "the bomb should be about 1 MB"
$PY - "$dir/deep.fcap" <<'PY'
import json, struct, sys
depth = 10**6
head = '{"sample_rate_hz": 1000, "columns": [{"name": "sin", "type": "f64"}, {"name": "cos", "type": "f64"}], "x": ' + "[" * depth + "]" * depth + "}"
with open(sys.argv[1], "wb") as f:
    f.write(b"FRNGCAP1" + struct.pack("<I", len(head)) + head.encode() + struct.pack("<dd", 0.5, 0.25) * 4)
PY

# upload FILE NAME: POSTs FILE while polling health every 20 ms and the service's memory;
# writes $dir/NAME.json {status, body, health: {n, failed, max_ms}, hwm_kib, rss_kib}.
upload() {
  timeout 180 $PY - "$URL" "$TOKEN" "$pid" "$1" > "$dir/$2.json" <<'PY'
import http.client, json, sys, threading, time, urllib.parse
url, token, pid, path = sys.argv[1:5]
u = urllib.parse.urlsplit(url)
def status():
    kib = {}
    for line in open(f"/proc/{pid}/status"):
        k, _, v = line.partition(":")
        if k in ("VmRSS", "VmHWM"): kib[k] = int(v.split()[0])
    return kib
out = {}
def post():
    c = http.client.HTTPConnection(u.hostname, u.port, timeout=120)
    body = open(path, "rb").read()
    c.request("POST", "/api/v1/captures", body, {"Authorization": "Bearer " + token, "Content-Type": "application/octet-stream"})
    r = c.getresponse()
    out["status"], out["body"] = r.status, r.read().decode()
t = threading.Thread(target=post); t.start()
n = failed = 0; worst = 0.0; rss = 0
while t.is_alive() or n == 0:
    a = time.monotonic()
    try:
        c = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
        c.request("GET", "/api/v1/health"); r = c.getresponse(); r.read()
        failed += r.status != 200
    except OSError:
        failed += 1
    worst = max(worst, time.monotonic() - a); n += 1
    rss = max(rss, status()["VmRSS"])
    time.sleep(0.02)
t.join()
s = status()
out.update(health={"n": n, "failed": failed, "max_ms": round(worst * 1e3, 1)}, hwm_kib=s["VmHWM"], rss_kib=max(rss, s["VmRSS"]))
print(json.dumps(out))
PY
}
field() { $PY -c 'import json,sys; v=json.load(open(sys.argv[1])); [v := v[k] for k in sys.argv[2].split(".")]; print(v)' "$dir/$1.json" "$2"; }
body() { $PY -c 'import json,sys; v=json.loads(json.load(open(sys.argv[1]))["body"]); [v := v[k] for k in sys.argv[2].split(".")]; print(v)' "$dir/$1.json" "$2"; }
check_memory() {  # NAME: peak and health during that upload
  local hwm; hwm=$(field "$1" hwm_kib)
  echo "$1: HTTP $(field "$1" status), VmHWM $hwm KiB (idle VmRSS $idle_kib KiB, +$((hwm - idle_kib)) KiB), health $(field "$1" health.n) answers, worst $(field "$1" health.max_ms) ms"
  [ $((hwm - idle_kib)) -le $BOUND_KIB ] || fail "$1: peak resident memory $hwm KiB is more than 64 MiB over idle ($idle_kib KiB)"
  [ "$(field "$1" health.failed)" = 0 ] || fail "$1: health failed $(field "$1" health.failed) of $(field "$1" health.n) times"
}

# Quota 200 MiB: the first 128 MiB capture fits, a second does not (on disk both are 130 KB).
start --upload-quota-mb 200
curl -sS --max-time 10 "${URL}api/v1/health" > /dev/null || fail "health"
sleep 0.5
idle_kib=$(awk '/^VmRSS:/ {print $2}' /proc/$pid/status)

upload "$dir/bomb.sr" bomb
check_memory bomb
[ "$(field bomb status)" = 413 ] || fail "the bomb should be 413, got $(field bomb status): $(field bomb body)"
[ "$(body bomb error.code)" = capture_too_large ] || fail "bomb: error code $(body bomb error.code)"
msg=$(body bomb error.message)
grep -q "1073741824 bytes" <<<"$msg" && grep -q "512 MiB" <<<"$msg" && grep -q -- "--max-upload-expanded-mb" <<<"$msg" \
  || fail "bomb: the message should name its size, the limit and the option: $msg"

upload "$dir/lie.sr" lie
check_memory lie
[ "$(field lie status)" = 400 ] || fail "the lying bomb should be 400, got $(field lie status): $(field lie body)"
body lie error.message | grep -q "decompresses to more than its declared size" || fail "lie: $(body lie error.message)"

upload "$dir/ok.sr" ok
check_memory ok
[ "$(field ok status)" = 201 ] || fail "128 MiB of samples within the limits should be accepted, got $(field ok status): $(field ok body)"
[ "$(body ok samples)" = 16777216 ] || fail "ok: samples $(body ok samples)"
[ "$(body ok expanded_bytes)" -ge $((128 << 20)) ] || fail "ok: expanded_bytes $(body ok expanded_bytes)"

upload "$dir/ok.sr" again
check_memory again
[ "$(field again status)" = 507 ] || fail "a second 128 MiB capture should exceed the 200 MiB quota, got $(field again status): $(field again body)"
[ "$(body again error.code)" = quota_exceeded ] || fail "again: $(field again body)"
body again error.message | grep -q "expand" || fail "again: the message should say the quota counts expanded sizes: $(body again error.message)"

upload "$dir/deep.fcap" deep
check_memory deep
[ "$(field deep status)" = 400 ] || fail "deep header: $(field deep status) $(field deep body)"
body deep error.message | grep -q "nests deeper than 128" || fail "deep: $(body deep error.message)"
kill -0 $pid || fail "the service died"
ls "$dir/data/captures" | grep -c '\.upload\.json$' | grep -qx 1 || fail "exactly one capture should be kept: $(ls "$dir/data/captures")"
stop

# The limit is the operator's: with --max-upload-expanded-mb 100 the 128 MiB capture is 413.
start --max-upload-expanded-mb 100
upload "$dir/ok.sr" small
[ "$(field small status)" = 413 ] && body small error.message | grep -q "100 MiB" || fail "--max-upload-expanded-mb 100: $(field small body)"
stop

# The CLI: clear errors, exit 2 (not std::bad_alloc, not a crash).
expect_error() {  # expect_error PATTERN cmd...
  local pat="$1"; shift
  set +e; msg=$(timeout 120 "$@" 2>&1); rc=$?; set -e
  [ $rc -eq 2 ] || fail "expected exit 2, got $rc: $* ($msg)"
  grep -q -- "$pat" <<<"$msg" || fail "expected '$pat' in: $msg"
}
expect_error "nests deeper than 128" "$FRINGE" estimate "$dir/deep.fcap" --estimator atan2 -q -o "$dir/e.csv"
expect_error "more than its declared size" "$FRINGE" estimate "$dir/lie.sr" --estimator atan2 -q -o "$dir/e.csv"
expect_error "more than the 512 MiB allowed (a limit against ZIP bombs) (--max-expanded-mb)" "$FRINGE" estimate "$dir/bomb.sr" --estimator atan2 -q -o "$dir/e.csv"
expect_error "more than the 100 MiB allowed" "$FRINGE" estimate "$dir/ok.sr" --estimator atan2 --max-expanded-mb 100 -q -o "$dir/e.csv"
echo "cli_serve_memory: all checks passed"
