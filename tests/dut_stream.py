#!/usr/bin/python3
"""A DUT's position stream for tests (docs/dut-readouts.md "Line-oriented position stream"):
the words of a DUT that reads a constant electrical frequency F_HZ from t = 0 (theta = 2 pi F t)
with a latency, M counts per electrical cycle, at WORD_RATE_HZ, up to T_END_S.

  dut_stream.py F_HZ LATENCY_S M WORD_RATE_HZ T_END_S [--flag-every K] [--garbage-every K]
                [--serve] [--cut FRACTION]

--flag-every K: every K-th word carries the DUT's error flag E; --garbage-every K: a malformed
line before every K-th word. Without --serve the lines go to stdout; with it, a TCP server on
127.0.0.1 prints "port N" and sends them to the first client (the first FRACTION of the bytes
with --cut, then closes)."""
import argparse, math, socket, sys

p = argparse.ArgumentParser()
p.add_argument("f_hz", type=float); p.add_argument("latency_s", type=float); p.add_argument("m", type=int)
p.add_argument("word_rate_hz", type=float); p.add_argument("t_end_s", type=float)
p.add_argument("--flag-every", type=int, default=0); p.add_argument("--garbage-every", type=int, default=0)
p.add_argument("--serve", action="store_true"); p.add_argument("--cut", type=float, default=1.0)
a = p.parse_args()

out = []
k = 0
while True:
    t = (k + 0.5) / a.word_rate_hz
    if t >= a.t_end_s:
        break
    cyc = a.f_hz * (t - a.latency_s)
    count = int(math.floor((cyc - math.floor(cyc)) * a.m)) % a.m
    if a.garbage_every and k % a.garbage_every == 1:
        out.append("1.0 2 3 4\n")
    flag = " E" if a.flag_every and k % a.flag_every == 2 else ""
    out.append("%.9f %d%s\n" % (t, count, flag))
    k += 1
data = "".join(out).encode()
if not a.serve:
    sys.stdout.buffer.write(data)
    sys.exit(0)
s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
s.bind(("127.0.0.1", 0)); s.listen(1); s.settimeout(60)
print("port", s.getsockname()[1], flush=True)
c, _ = s.accept()
c.sendall(data[: int(len(data) * a.cut)])
c.close(); s.close()
