#!/usr/bin/python3
"""fringe's estimators and generator beside numpy peers, timed in the same run.

Usage: /usr/bin/python3 perf/peers.py BUILD_DIR [--repetitions N] [--min-time S] [--quick]

Times, on 65536-sample blocks (the block of build/perf/bench_estimators and of
bench_signal_gen's BM_paper_diffraction/65536):
  - numpy's arctan2 alone, and arctan2 followed by unwrap, on the paper signal;
  - a numpy reference generator of the paper fixture (fixtures/scenarios/paper-duty1p6.json:
    the diffraction model of docs/model.md at kappa 1.1149, constant velocity, additive and
    gain noise, 16-bit ADC), vectorised over the block, the same physics and parameters as
    the C++ generator's benchmark (its normals come from numpy's generator, not the
    ziggurat of signal_gen/noise.cpp, so the numbers differ, not the model);
and fringe's benchmarks (Google Benchmark; ekf-auto also on a continuous signal, bench_ekf_auto
steady), in rounds that alternate the two sides (so a
change in the machine's load falls on both), and prints, from the medians over the rounds,
one table of rates (per second of CPU time on both sides), ratios fringe / numpy and the
targets. Exit status 0 whether or not a target is met (the machine's load moves every
figure); non-zero when a program is missing or fails, or its output lacks a benchmark. --quick (the ctest) runs each side briefly.
"""

import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BLOCK = 65536


def load_fixture():
    with open(os.path.join(ROOT, "fixtures/scenarios/paper-duty1p6.json")) as f:
        sc = json.load(f)
    with open(os.path.join(ROOT, "fixtures/scenarios", sc["encoder"])) as f:
        enc = json.load(f)
    return sc, enc


class PaperModel:
    """The paper fixture's signal in numpy: docs/MODEL.md's diffraction model.

    V_s = Vmax [w/2 + sum_m B_m cos(m (theta - pi/2))], V_c = Vmax [w/2 + sum_m B_m cos(m (theta + delta))]
    with B_m = (2/m) max(0, 1 - m/(2 kappa)) sin(m w/2), m = 1 .. ceil(2 kappa) - 1; then the
    front end (gain noise, reference, channel gains and offsets, additive noise) and the ADC.
    """

    def __init__(self, sc, enc, seed=1):
        optics = enc.get("optics", {})
        geo = enc.get("geometry", {})
        liss = enc.get("lissajous", {})
        noise = enc.get("noise", {})
        adc = enc.get("adc", {})
        self.fs = float(sc["sample_rate_hz"])
        lines = float(enc["lines_per_rev"])
        self.omega_e = 2 * math.pi * float(sc["motion"]["electrical_freq_hz"])  # lines * velocity
        self.theta0 = lines * float(sc["motion"].get("phi0_rad", 0.0))
        w = float(optics["aperture_w_rad"])
        vmax = float(enc.get("vmax_v", 1.0))
        gap = 0.5 * (float(geo["gap_d1_cm"]) + float(geo["gap_d2_cm"]))
        kappa = float(optics.get("kappa_ref", 1.0)) * float(optics["gap_ref_cm"]) / gap
        M = max(0, math.ceil(2 * kappa) - 1)
        delta = float(liss.get("quadrature_error_rad", 0.0))
        m = np.arange(1, M + 1, dtype=float)
        self.m = m[:, None]
        self.amp = (vmax * (2 / m) * np.maximum(0.0, 1 - m / (2 * kappa)) * np.sin(m * w / 2))[:, None]
        self.ps, self.qs = np.cos(m * math.pi / 2)[:, None], np.sin(m * math.pi / 2)[:, None]
        self.pc, self.qc = np.cos(m * delta)[:, None], -np.sin(m * delta)[:, None]
        self.dc = vmax * w / 2
        ref = (enc.get("front_end") or {}).get("reference_v")
        self.vref = self.dc if ref is None else float(ref)
        eps = float(liss.get("gain_mismatch", 0.0))
        self.g_s, self.g_c = 1 + eps / 2, 1 - eps / 2
        self.off_s, self.off_c = float(liss.get("offset_sin_v", 0.0)), float(liss.get("offset_cos_v", 0.0))
        self.sigma_add = float(noise.get("sigma_add_v", 0.0))
        self.sigma_gain = float(noise.get("sigma_gain", 0.0))
        self.bits = int(adc.get("bits", 0))
        self.lo, hi = float(adc.get("min_v", -1.25)), float(adc.get("max_v", 1.25))
        self.q = (hi - self.lo) / 2**self.bits if self.bits else 0.0
        self.top = 2.0**self.bits - 1
        self.rng = np.random.default_rng(seed)

    def generate(self, first, n):
        """(sin_v, cos_v, theta_rad, omega_rad_s) of samples first .. first + n - 1."""
        t = (first + np.arange(n, dtype=float)) / self.fs
        theta = self.theta0 + self.omega_e * t
        omega = np.full(n, self.omega_e)
        mt = self.m * theta  # harmonics x samples
        C, S = np.cos(mt), np.sin(mt)
        rs = self.dc + (self.amp * (self.ps * C + self.qs * S)).sum(axis=0)
        rc = self.dc + (self.amp * (self.pc * C + self.qc * S)).sum(axis=0)
        z = self.rng.standard_normal((3, n))
        g = 1 + self.sigma_gain * z[2]
        vs = self.g_s * (g * rs - self.vref) + self.off_s + self.sigma_add * z[0]
        vc = self.g_c * (g * rc - self.vref) + self.off_c + self.sigma_add * z[1]
        if self.bits:
            vs = self.lo + np.clip(np.floor((vs - self.lo) / self.q + 0.5), 0, self.top) * self.q
            vc = self.lo + np.clip(np.floor((vc - self.lo) / self.q + 0.5), 0, self.top) * self.q
        return vs, vc, theta, omega


def rate(fn, n, reps, min_time):
    """Median over reps of items per second of CPU time (as Google Benchmark counts its
    items_per_second, so a loaded machine moves both sides alike), each repetition looping
    fn for at least min_time s."""
    fn()  # warm
    rates = []
    for _ in range(reps):
        k, t0 = 0, time.process_time()
        while True:
            fn()
            k += 1
            dt = time.process_time() - t0
            if dt >= min_time:
                break
        rates.append(k * n / dt)
    rates.sort()
    return rates[len(rates) // 2]


def fringe_rates(build, reps, min_time):
    """Medians of items_per_second of the benchmarks peers.py compares, by name."""
    out = {}
    for prog, filt in (("bench_estimators", "^run/(atan2|ekf_diffraction_cv|ekf_diffraction_agc_kappa_bias|ekf_selfcal|ekf_auto)$"),
                       ("bench_signal_gen", "^BM_paper_diffraction/65536$"),
                       ("bench_ekf_auto", "^steady$")):
        exe = os.path.join(build, "perf", prog)
        if not os.access(exe, os.X_OK):
            sys.exit(f"peers.py: {exe} not found (build the perf programs first)")
        cmd = [exe, f"--benchmark_filter={filt}", f"--benchmark_repetitions={reps}",
               f"--benchmark_min_time={min_time}", "--benchmark_report_aggregates_only=true",
               "--benchmark_format=json"]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            sys.stderr.write(r.stderr)
            sys.exit(2)
        for b in json.loads(r.stdout)["benchmarks"]:
            if b.get("aggregate_name") == "median" or (reps == 1 and b.get("run_type") == "iteration"):
                out[b["run_name"]] = b["items_per_second"]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("build", help="the build folder (holding perf/bench_estimators and perf/bench_signal_gen)")
    ap.add_argument("--repetitions", type=int, default=5, help="medians of this many alternating rounds (default 5)")
    ap.add_argument("--min-time", type=float, default=0.5, help="seconds per benchmark per round (default 0.5)")
    ap.add_argument("--quick", action="store_true", help="one short repetition of each (a smoke test)")
    a = ap.parse_args()
    reps, min_time = (1, 0.05) if a.quick else (a.repetitions, a.min_time)

    sc, enc = load_fixture()
    model = PaperModel(sc, enc)
    s, c, theta, _ = model.generate(0, BLOCK)
    # The model's own check: its phase, unwrapped, is the truth to within the noise.
    err = np.unwrap(np.arctan2(s - s.mean(), c - c.mean())) - theta
    err -= err.mean()
    if not np.all(np.isfinite(s)) or np.abs(err).max() > 0.2:
        sys.exit(f"peers.py: the numpy model's phase is off the truth by {np.abs(err).max():.3g} rad")

    first = [0]

    def gen():
        model.generate(first[0], BLOCK)
        first[0] += BLOCK

    # Rounds that alternate the two sides, one repetition of each per round, so that a change
    # in the machine's load (shared cores) falls on both; the medians over the rounds.
    rounds = []
    for _ in range(reps):
        r = {"np_atan2": rate(lambda: np.arctan2(s, c), BLOCK, 1, min_time),
             "np_unwrap": rate(lambda: np.unwrap(np.arctan2(s, c)), BLOCK, 1, min_time),
             "np_gen": rate(gen, BLOCK, 1, min_time)}
        r.update(fringe_rates(a.build, 1, min_time))
        rounds.append(r)

    def median(key):
        v = sorted(r[key] for r in rounds if key in r)
        return v[len(v) // 2] if v else None

    np_atan2, np_unwrap, np_gen = median("np_atan2"), median("np_unwrap"), median("np_gen")
    fr = {k: median(k) for k in rounds[0] if not k.startswith("np_")}
    load = os.getloadavg()[0]

    def f(name):
        if name not in fr:
            sys.exit(f"peers.py: no result for benchmark {name}")
        return fr[name]

    rows = [
        ("atan2, samples/s", f("run/atan2"), "numpy arctan2", np_atan2, ">= 0.8x numpy", f("run/atan2") >= 0.8 * np_atan2),
        ("", None, "numpy arctan2 + unwrap", np_unwrap, "", None),
        ("generator, paper fixture, pairs/s", f("BM_paper_diffraction/65536"), "numpy reference model", np_gen, "150 M",
         f("BM_paper_diffraction/65536") >= 150e6),
        ("ekf-diffraction CV", f("run/ekf_diffraction_cv"), "", None, "20 M", f("run/ekf_diffraction_cv") >= 20e6),
        ("ekf-diffraction, 6 states", f("run/ekf_diffraction_agc_kappa_bias"), "", None, "7 M",
         f("run/ekf_diffraction_agc_kappa_bias") >= 7e6),
        ("ekf-selfcal", f("run/ekf_selfcal"), "", None, "5 M", f("run/ekf_selfcal") >= 5e6),
        ("ekf-auto", f("run/ekf_auto"), "", None, "10 M", f("run/ekf_auto") >= 10e6),
        # bench_estimators repeats one block, whose phase jump where it wraps ekf-auto takes
        # for a new signal (it re-acquires and replays every block); a continuous signal too
        ("ekf-auto, continuous signal", f("steady"), "", None, "10 M", f("steady") >= 10e6),
    ]
    print(f"perf/peers.py: {BLOCK}-sample blocks, medians of {reps} alternating rounds of {min_time} s; numpy {np.__version__}; "
          f"load average {load:.2f}; {time.strftime('%Y-%m-%d %H:%M %Z')}")
    print("| what | fringe | peer | peer rate | fringe / peer | target | met |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    last = None
    for what, fv, peer, pv, target, met in rows:
        fv = last if fv is None else fv
        last = fv
        ratio = f"{fv / pv:.2f}" if pv else "-"
        print(f"| {what} | {fv / 1e6:.1f} M/s | {peer or '-'} | {pv / 1e6:.1f} M/s | {ratio} | {target or '-'} | "
              f"{'-' if met is None else ('yes' if met else 'no')} |" if pv else
              f"| {what} | {fv / 1e6:.1f} M/s | - | - | - | {target} | {'yes' if met else 'no'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
