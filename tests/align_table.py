#!/usr/bin/python3
"""The table "Measured through the run" in docs/alignment.md, every row of it, measured.

Each row names a bench (the own-clock loopback, or a SCPI generator and digitizer emulated by
`fringe instrument-sim` over TCP on 127.0.0.1), the link it simulates and what the alignment
must do: `ok` (then the run must PASS and the measured delay and clock offset must match the
simulated ones: the simulators resample with their own interpolators, an independent reference)
or `aligned` (the same, whatever the verdict: the estimators see what the alignment left out),
or `refused: TEXT` (the run is an ERROR, exit 2, whose message holds TEXT, and nothing is scored).
The measured columns are compared with the documented ones.

usage: align_table.py FRINGE SOURCE_DIR [--print | --write]
  --print  print the table as measured (rows in the documented order)
  --write  rewrite the table in docs/alignment.md with the measured values
"""
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time

FRINGE, SRC = sys.argv[1], sys.argv[2]
MODE = sys.argv[3] if len(sys.argv) > 3 else ""
DOC = os.path.join(SRC, "docs", "alignment.md")
FS = 100000.0
# Bounds every `ok` row must meet, and how far a documented measurement may lie from this one.
MAX_DELAY_ERR_SAMPLES, MAX_PPM_ERR = 0.01, 0.05
DOC_DELAY_TOL_SAMPLES, DOC_PPM_TOL = 2e-3, 2e-3
HEADER = "| bench | link | expected | delay error (samples) | clock error (ppm) | ambiguity_z |"
LOOPBACK_BASE = {"own_clock": "1", "dac_bits": "16", "adc_bits": "16", "noise_v": "1e-4", "gain": "0.95", "offset_v": "0.002"}


def read_rows():
    lines = open(DOC).read().split("\n")
    i = lines.index(HEADER)
    rows, j = [], i + 2
    while j < len(lines) and lines[j].startswith("|"):
        cells = [c.strip() for c in lines[j].strip().strip("|").split("|")]
        assert len(cells) == 6, lines[j]
        rows.append(cells)
        j += 1
    return lines, i, j, rows


def link_of(cell):
    m = re.fullmatch(r"`([^`]*)`", cell)
    assert m, f"link cell {cell!r} is not `key=value ...`"
    return dict(kv.split("=", 1) for kv in m.group(1).split())


def scenario(base_fixture, device_out, device_in, tmp, duration_s):
    j = json.load(open(os.path.join(SRC, "fixtures", "scenarios", base_fixture)))
    j["duration_s"] = duration_s
    j["settle_s"] = 0.02
    j["device"] = {"output": device_out, "input": device_in}
    j["limits"] = [l for l in j["limits"] if l["metric"] in ("rms_rad", "slipped_samples")]
    path = os.path.join(tmp, "scenario.json")
    json.dump(j, open(path, "w"))
    return path


def run(path, tmp):
    rep = os.path.join(tmp, "report.json")
    if os.path.exists(rep):
        os.remove(rep)
    p = subprocess.run([FRINGE, "run", path, "--no-db", "-q", "--report", rep], capture_output=True, text=True, timeout=120)
    if not os.path.exists(rep):  # refused before running: no report, the message on stderr
        return p.returncode, p.stderr, {"verdict": "no report", "error": p.stderr.strip(), "samples": {"processed": 0}}
    return p.returncode, p.stderr, json.load(open(rep))


def loopback_row(link, tmp):
    duration_s = float(link.pop("duration_s", "0.1"))
    q = dict(LOOPBACK_BASE)
    q.update(link)
    uri = "loopback:?" + "&".join(f"{k}={v}" for k, v in q.items())
    true_delay = float(q.get("delay_s", 0))
    return run(scenario("loopback-two-clocks.json", uri, uri, tmp, duration_s), tmp), true_delay, float(q.get("clock_ppm", 0))


def scpi_row(link, tmp):
    pre = int(link.pop("pretrigger", "256"))
    duration_s = float(link.pop("duration_s", "0.1"))
    args = [FRINGE, "instrument-sim", "--bench", "--port", "0", "--exit-after", "100"]
    for k, v in link.items():
        args.append(f"--{k.replace('_', '-')}={v}")
    log = open(os.path.join(tmp, "isim.log"), "w+")
    sim = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
    try:
        gen = dig = None
        for _ in range(200):
            log.seek(0)
            text = log.read()
            gen = re.search(r"^instrument-sim generator (scpi[^?\s]*)", text, re.M)
            dig = re.search(r"^instrument-sim digitizer (scpi[^?\s]*)", text, re.M)
            if gen and dig:
                break
            if sim.poll() is not None:
                raise AssertionError("instrument-sim exited: " + text)
            time.sleep(0.05)
        assert gen and dig, "instrument-sim did not start"
        out = gen.group(1) + "?model=keysight-33500b"
        inp = dig.group(1) + f"?model=generic-scope&pretrigger_samples={pre}"
        res = run(scenario("scpi-awg-digitizer.json", out, inp, tmp, duration_s), tmp)
    finally:
        sim.send_signal(signal.SIGTERM)
        try:
            sim.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.wait()
    true_delay = pre / FS + float(link.get("delay_s", "15e-6"))
    return res, true_delay, float(link.get("clock_ppm", "20"))


def num(cell):
    try:
        return float(cell)
    except ValueError:
        return None


def g2(x):
    return f"{x:.2g}" if x != 0 else "0"


def main():
    lines, i, j, rows = read_rows()
    assert rows, "the table has no rows"
    failures, out_rows = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for bench, link_cell, expected, d_doc, p_doc, z_doc in rows:
            link = link_of(link_cell)
            what = f"{bench} {link_cell}"
            t0 = time.time()
            if bench == "loopback":
                (code, err, rep), true_delay, true_ppm = loopback_row(dict(link), tmp)
            elif bench == "scpi":
                (code, err, rep), true_delay, true_ppm = scpi_row(dict(link), tmp)
            else:
                raise AssertionError(f"unknown bench {bench!r}")
            a = rep.get("alignment") or {}
            cells = [bench, link_cell, expected]
            if expected in ("ok", "aligned"):
                d_err = (a.get("delay_s", float("nan")) - true_delay) * FS if a.get("ok") else float("nan")
                p_err = a.get("clock_offset_ppm", float("nan")) - true_ppm if a.get("ok") else float("nan")
                z = (a.get("confidence") or {}).get("ambiguity_z")
                cells += [g2(d_err), g2(p_err), "inf" if z is None else f"{z:.1g}"]
                if not a.get("ok") or (expected == "ok" and (code != 0 or rep["verdict"] != "PASS")):
                    failures.append(f"{what}: expected ok, got exit {code} {rep['verdict']}: {rep.get('error')}")
                elif not (abs(d_err) <= MAX_DELAY_ERR_SAMPLES and abs(p_err) <= MAX_PPM_ERR):
                    failures.append(f"{what}: delay error {d_err} samples, clock error {p_err} ppm beyond {MAX_DELAY_ERR_SAMPLES}, {MAX_PPM_ERR}")
                elif z is not None and z < 10:
                    failures.append(f"{what}: ambiguity_z {z} < 10")
                elif MODE != "--write":
                    if num(d_doc) is None or abs(num(d_doc) - d_err) > DOC_DELAY_TOL_SAMPLES:
                        failures.append(f"{what}: documented delay error {d_doc}, measured {d_err:.3g} samples")
                    if num(p_doc) is None or abs(num(p_doc) - p_err) > DOC_PPM_TOL:
                        failures.append(f"{what}: documented clock error {p_doc}, measured {p_err:.3g} ppm")
            else:
                m = re.fullmatch(r"refused: (.+)", expected)
                assert m, f"{what}: expected must be 'ok' or 'refused: TEXT', got {expected!r}"
                cells += ["-", "-", "-"]
                msg = rep.get("error") or ""
                if code != 2 or rep["verdict"] != "ERROR" or m.group(1) not in msg:
                    failures.append(f"{what}: expected refused '{m.group(1)}', got exit {code} {rep['verdict']}: {msg}")
                elif rep["samples"]["processed"] != 0:
                    failures.append(f"{what}: refused but {rep['samples']['processed']} samples scored")
                elif (d_doc, p_doc, z_doc) != ("-", "-", "-"):
                    failures.append(f"{what}: a refused row has no measurements")
            row = "| " + " | ".join(cells) + " |"
            out_rows.append(row)
            print(f"{row}    ({time.time() - t0:.1f} s; {(rep.get('error') or 'ok')[:160]})", flush=True)
    if MODE == "--write":
        lines[i + 2:j] = out_rows
        open(DOC, "w").write("\n".join(lines))
        print("rewrote", DOC)
    if failures:
        print("\n".join("FAIL: " + f for f in failures), file=sys.stderr)
        sys.exit(1)
    print(f"align_table: {len(rows)} rows ok")


main()
