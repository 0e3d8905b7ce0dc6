#!/usr/bin/python3
"""An ABZ interface board's answer, as a logic analyser records it, for tests: a sigrok session
file (.sr) with channels A, B, Z of a board that reads a constant electrical frequency F_HZ from
t = 0 (theta = 2 pi F t) with a latency, N A/B periods per electrical cycle (4N counts), sampled
at LOGIC_RATE_HZ up to T_END_S. Conventions of docs/abz.md: count c while the board's angle is in
[c, c+1) steps, A leading B forward (00 -> 10 -> 11 -> 01), Z high while c = 0 (mod 4N).

  abz_sr.py F_HZ LATENCY_S N LOGIC_RATE_HZ T_END_S OUT.sr [--glitches K] [--drop-index K]

--glitches K: K single samples, spread over the capture, where A and B both flip (two illegal
transitions each: into the glitch and out of it). --drop-index K: Z stays low through K index
cells spread over the capture (a lost index each)."""
import argparse, io, zipfile

import numpy as np

p = argparse.ArgumentParser()
p.add_argument("f_hz", type=float); p.add_argument("latency_s", type=float); p.add_argument("n", type=int)
p.add_argument("rate_hz", type=float); p.add_argument("t_end_s", type=float); p.add_argument("out")
p.add_argument("--glitches", type=int, default=0); p.add_argument("--drop-index", type=int, default=0)
a = p.parse_args()

samples = int(round(a.t_end_s * a.rate_hz))
t_s = np.arange(samples) / a.rate_hz
cycles = a.f_hz * (t_s - a.latency_s)
count = np.floor(cycles * 4 * a.n).astype(np.int64)
state = np.mod(count, 4)
a_line = np.isin(state, (1, 2)).astype(np.uint8)  # 00 -> 10 -> 11 -> 01
b_line = np.isin(state, (2, 3)).astype(np.uint8)
z_line = (np.mod(count, 4 * a.n) == 0).astype(np.uint8)
for k in range(a.glitches):
    i = int((k + 0.5) * samples / a.glitches)
    # Away from an edge and from the index, so each glitch is exactly two illegal transitions.
    while state[i - 1] != state[i] or state[i + 1] != state[i] or z_line[i - 1] or z_line[i + 1]:
        i += 1
    a_line[i] ^= 1
    b_line[i] ^= 1
if a.drop_index:
    starts = np.flatnonzero(np.diff(z_line.astype(np.int8)) == 1) + 1
    for k in range(a.drop_index):
        s0 = starts[int((k + 0.5) * len(starts) / a.drop_index)]
        e0 = s0
        while e0 < samples and z_line[e0]:
            e0 += 1
        z_line[s0:e0] = 0
data = (a_line | (b_line << 1) | (z_line << 2)).astype(np.uint8).tobytes()
meta = ("[global]\nsigrok version=0.5.2\n\n[device 1]\ncapturefile=logic-1\ntotal probes=3\n"
        "samplerate=%d\nunitsize=1\nprobe1=A\nprobe2=B\nprobe3=Z\n" % int(a.rate_hz))
with zipfile.ZipFile(a.out, "w", zipfile.ZIP_DEFLATED) as z:
    z.writestr("version", "2")
    z.writestr("metadata", meta)
    z.writestr("logic-1-1", data)
print("samples", samples, "glitches", a.glitches, "dropped index pulses", a.drop_index)
