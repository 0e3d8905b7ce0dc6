#!/usr/bin/env bash
# Load figures for fringe serve on 127.0.0.1 (README "Performance"): wrk against the GET
# report endpoints, 100 concurrent live-progress (SSE) clients on one running run with
# the event latency they see, and /api/v1/health latency while capture evaluations and runs
# keep every worker busy. Bounded in time; stops what it starts.
#   perf/load_serve.sh build/server/fringe [seconds]
set -euo pipefail
FRINGE="${1:-build/server/fringe}"; SECS="${2:-10}"
PY=/usr/bin/python3
. "$(dirname "$0")/../tests/lib.sh"
command -v wrk >/dev/null || { echo "wrk missing: scripts/setup --test" >&2; exit 2; }
dir=$(mktemp -d); pid=
trap 'kill $pid 2>/dev/null || true; rm -rf "$dir"' EXIT
"$FRINGE" serve --bind 127.0.0.1:0 --data "$dir" --threads "${THREADS:-2}" > "$dir/out" 2> "$dir/log" &
pid=$!
URL=$(poll_log "$dir/out" 's/.*serving \(http:[^ ]*\) .*/\1/p' 100 0.1) || { cat "$dir/log" >&2; exit 1; }
T=$(cat "$dir/token")
id=$(curl -s -X POST -H "Authorization: Bearer $T" -d '{"fixture":"fig10c-loopback"}' "${URL}api/v1/runs" | $PY -c 'import json,sys; print(json.load(sys.stdin)["id"])')
for _ in $(seq 100); do curl -s "${URL}api/v1/runs/$id" | grep -q '"status":"done"' && break; sleep 0.1; done
echo "fringe serve $URL, $(nproc) cores shared by server and load; run $id"
for ep in report.json report.xml traces; do
  bytes=$(curl -s "${URL}api/v1/runs/$id/$ep" | wc -c)
  out=$(timeout $((SECS + 20)) wrk -t1 -c32 -d"${SECS}s" --latency "${URL}api/v1/runs/$id/$ep")
  rps=$(echo "$out" | awk '/Requests\/sec/ {print $2}')
  p50=$(echo "$out" | awk '$1=="50%" {print $2}'); p99=$(echo "$out" | awk '$1=="99%" {print $2}')
  errs=$(echo "$out" | awk '/Non-2xx|Socket errors/ {print}' | tr '\n' ' ')
  printf 'GET %-12s %7s bytes: %9s req/s, p50 %s, p99 %s %s\n' "$ep" "$bytes" "$rps" "$p50" "$p99" "$errs"
done

# 100 SSE clients on one long run.
long=$(curl -s -X POST -H "Authorization: Bearer $T" -d '{"fixture":"perf-1e7"}' "${URL}api/v1/runs" | $PY -c 'import json,sys; print(json.load(sys.stdin)["id"])')
$PY - "$URL" "$long" "$T" <<'PY'
import http.client, json, sys, threading, time, urllib.parse, urllib.request
url, run, token = sys.argv[1], sys.argv[2], sys.argv[3]
u = urllib.parse.urlparse(url)
N, HOLD_S = 100, 3.0
lat, counts, ended, errors = [], [0] * N, [False] * N, []
lock = threading.Lock()
def client(i):
    try:
        c = http.client.HTTPConnection(u.hostname, u.port, timeout=30)
        c.request("GET", f"/api/v1/runs/{run}/events")
        r = c.getresponse()
        assert r.status == 200, r.status
        ev = None
        for raw in r:
            line = raw.decode().rstrip("\n")
            if line.startswith("event: "):
                ev = line[7:]
            elif line.startswith("data: "):
                s = json.loads(line[6:])
                with lock:
                    counts[i] += 1
                    if ev == "progress" and s["progress"]["done"] > 0:
                        lat.append(time.time() * 1000 - s["updated_unix_ms"])
                if ev == "end":
                    ended[i] = True
                    return
    except Exception as e:
        with lock: errors.append(repr(e))
ts = [threading.Thread(target=client, args=(i,), daemon=True) for i in range(N)]
for t in ts: t.start()
time.sleep(HOLD_S)
held = sum(1 for c in counts if c > 0)
req = urllib.request.Request(f"{url}api/v1/runs/{run}/cancel", method="POST", data=b"", headers={"Authorization": "Bearer " + token})
urllib.request.urlopen(req, timeout=10).read()
for t in ts: t.join(timeout=20)
lat.sort()
p = lambda q: lat[min(len(lat) - 1, int(q * len(lat)))] if lat else float("nan")
print(f"SSE: {held}/{N} clients receiving after {HOLD_S:.0f} s, {sum(ended)}/{N} got the end event, "
      f"{len(lat)} progress events, latency p50 {p(0.5):.0f} ms, p99 {p(0.99):.0f} ms, max {lat[-1] if lat else float('nan'):.0f} ms, errors {len(errors)}")
rc = 0 if held == N and sum(ended) == N and not errors else 1
if rc: sys.exit(rc)
PY

# /api/v1/health while the workers are saturated: EVALS evaluations of a 3e6-sample capture
# (the pool runs as many at once as there are workers, the rest wait) and two long runs.
"$FRINGE" gen "$(dirname "$0")/../fixtures/scenarios/fig10c-loopback.json" -o "$dir/big.fcap" --samples 3000000 -q
cap=$(curl -s -X POST -H "Authorization: Bearer $T" --data-binary @"$dir/big.fcap" "${URL}api/v1/captures" | $PY -c 'import json,sys; print(json.load(sys.stdin)["id"])')
$PY - "$URL" "$cap" "$T" "${EVALS:-6}" <<'PY'
import http.client, json, sys, threading, time, urllib.parse
url, cap, token, evals = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
u = urllib.parse.urlparse(url)
auth = {"Authorization": "Bearer " + token, "Content-Type": "application/json"}
def call(method, path, body=None, timeout=120):
    c = http.client.HTTPConnection(u.hostname, u.port, timeout=timeout)
    c.request(method, path, body=body, headers=auth)
    r = c.getresponse(); data = r.read(); c.close()
    return r.status, data
runs = [json.loads(call("POST", "/api/v1/runs", json.dumps({"fixture": "perf-1e7"}))[1])["id"] for _ in range(2)]
pending, statuses, lock = [evals], [], threading.Lock()
def evaluate():
    st, _ = call("POST", f"/api/v1/captures/{cap}/evaluate", json.dumps({"estimator": "atan2"}))
    with lock:
        statuses.append(st); pending[0] -= 1
t0 = time.time()
ts = [threading.Thread(target=evaluate, daemon=True) for _ in range(evals)]
for t in ts: t.start()
lat = []
while pending[0] > 0 and time.time() - t0 < 120:
    a = time.perf_counter()
    st, _ = call("GET", "/api/v1/health", timeout=10)
    lat.append((time.perf_counter() - a) * 1000)
    assert st == 200, st
    time.sleep(0.005)
wall = time.time() - t0
for t in ts: t.join(timeout=120)
for r in runs: call("POST", f"/api/v1/runs/{r}/cancel", b"")
lat.sort()
p = lambda q: lat[min(len(lat) - 1, int(q * len(lat)))]
print(f"health under load ({evals} evaluations of 3e6 samples + 2 runs, {wall:.1f} s): {len(lat)} requests, "
      f"p50 {p(0.5):.1f} ms, p99 {p(0.99):.1f} ms, max {lat[-1]:.1f} ms; evaluations {statuses.count(200)}/{evals} 200")
sys.exit(0 if statuses.count(200) == evals else 1)
PY
