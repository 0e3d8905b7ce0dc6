// Truth alignment across clocks (docs/alignment.md has the method, its assumptions and limits).
//   1. Coarse: integer-lag least squares of the record against the played onset (a template of
//      idle output followed by the first samples played), per-channel gain and offset solved in
//      closed form at every lag (FFT cross-correlation plus prefix sums). The idle part makes the
//      statistic see where the output starts, so a periodic signal's copies one period apart
//      score differently.
//   2. Fine: Gauss-Newton on (delay, clock ratio, gain and offset per channel) with the played
//      waveform interpolated band-limited (Kaiser-windowed sinc) at the warped times, over a
//      window that doubles from the onset to the whole record, so a clock offset cannot slip a
//      cycle on the way.
//   3. Decision: every coarse candidate is fitted, and the candidates are compared on the whole
//      record including the idle output before the onset and after the end. The best must beat
//      the next distinct one by min_ambiguity_z standard deviations, else the delay is ambiguous
//      (a periodic signal whose onset is not in the record) and the alignment is refused.
#include "server/analysis/align.hpp"
#include "signal_gen/base/constants.hpp"

#include <Eigen/Dense>
#include <unsupported/Eigen/FFT>

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdio>
#include <limits>
#include <vector>

namespace fringe {

namespace {

constexpr int kH = 24;         // interpolator half-width, samples
constexpr int kRes = 1024;     // kernel table rows per sample (384 KiB a table: stays in cache)
constexpr double kBeta = 9.0;  // Kaiser window shape

double bessel_i0(double x) {
    double sum = 1, term = 1;
    for (int k = 1; k < 200; ++k) {
        term *= (x / (2 * k)) * (x / (2 * k));
        sum += term;
        if (term < 1e-17 * sum) break;
    }
    return sum;
}
double bessel_i1(double x) {
    double term = x / 2, sum = term;
    for (int k = 1; k < 200; ++k) {
        term *= (x / 2) * (x / 2) / (k * (k + 1.0));
        sum += term;
        if (std::fabs(term) < 1e-17 * std::fabs(sum)) break;
    }
    return sum;
}

// Kernel K(x) = sinc(x) * kaiser(x / H) and its derivative as a polyphase table: row r holds
// the 2H tap weights for the fractional position f = r / kRes, so a value is two contiguous
// dot products blended linearly in f (error ~ (1/kRes)^2 / 8 of the signal's second
// derivative in samples: 3e-7 of the amplitude at 4 samples a cycle, 1e-9 at 100).
struct Kernel {
    static constexpr int kTaps = 2 * kH;
    std::vector<double> w, dw;  // (kRes + 1) rows of kTaps
    static void closed_form(double x, double& k, double& dk) {
        static const double i0b = bessel_i0(kBeta);
        const double ax = std::fabs(x);
        if (ax >= kH) { k = dk = 0; return; }
        const double px = kPi * ax;
        const double sinc = ax < 1e-12 ? 1.0 : std::sin(px) / px;
        const double dsinc = ax < 1e-12 ? 0.0 : (px * std::cos(px) - std::sin(px)) / (px * ax);
        const double r = ax / kH, s = std::sqrt(std::max(0.0, 1 - r * r));
        const double win = bessel_i0(kBeta * s) / i0b;
        // d win/dx = I1(beta s) beta ds/dx / I0(beta), ds/dx = -x / (H^2 s); finite as s -> 0.
        const double dwin = s > 1e-12 ? bessel_i1(kBeta * s) * kBeta * (-ax / (kH * kH * s)) / i0b : -kBeta * kBeta * ax / (2.0 * kH * kH * i0b);
        k = sinc * win;
        dk = (dsinc * win + sinc * dwin) * (x < 0 ? -1 : 1);
    }
    Kernel() : w((kRes + 1) * kTaps), dw((kRes + 1) * kTaps) {
        for (int r = 0; r <= kRes; ++r) {
            const double f = static_cast<double>(r) / kRes;
            for (int j = 0; j < kTaps; ++j) {
                const int k = j - kH + 1;  // tap at sample n0 + k, distance f - k
                closed_form(f - k, w[static_cast<std::size_t>(r * kTaps + j)], dw[static_cast<std::size_t>(r * kTaps + j)]);
            }
        }
    }
};

const Kernel& kernel() {
    static const Kernel k;
    return k;
}

// Both channels through the weights blended between two table rows: independent partial sums
// (a single running sum is bound by the add latency, ~4x slower).
inline void blend_dot(const double* w0, const double* w1, double al, const double* xs, const double* xc, double& vs, double& vc) {
    double ps[4] = {0, 0, 0, 0}, pc[4] = {0, 0, 0, 0};
    for (int j = 0; j < Kernel::kTaps; j += 4)
        for (int i = 0; i < 4; ++i) {
            const double w = w0[j + i] + al * (w1[j + i] - w0[j + i]);
            ps[i] += w * xs[j + i];
            pc[i] += w * xc[j + i];
        }
    vs = (ps[0] + ps[1]) + (ps[2] + ps[3]);
    vc = (pc[0] + pc[1]) + (pc[2] + pc[3]);
}

// The played pair as a band-limited function of generator time (idle 0 V outside it).
struct Played {
    const double* s;
    const double* c;
    std::size_t n;
    double fs;
    bool cyclic;
    // Values and (when ds is given) time derivatives (V, V/s) at generator time t.
    void eval(double t, double& vs, double& vc, double* ds = nullptr, double* dc = nullptr) const {
        vs = vc = 0;
        if (ds) *ds = *dc = 0;
        const double u = t * fs;
        if (!(u > -kH) || (!cyclic && u >= static_cast<double>(n) - 1 + kH)) return;
        const double fl = std::floor(u), a = (u - fl) * kRes;
        const auto n0 = static_cast<long long>(fl);
        const auto r = std::min(static_cast<long long>(a), static_cast<long long>(kRes - 1));
        const double al = a - static_cast<double>(r);
        const Kernel& K = kernel();
        const double* w0 = &K.w[static_cast<std::size_t>(r) * Kernel::kTaps];
        const double* w1 = w0 + Kernel::kTaps;
        const long long base = n0 - kH + 1;
        const auto nn = static_cast<long long>(n);
        const double* xs;
        const double* xc;
        double bs[Kernel::kTaps], bc[Kernel::kTaps];
        if (base >= 0 && base + Kernel::kTaps <= nn) {
            xs = s + base;
            xc = c + base;
        } else {  // at an edge: idle before, idle or wrapped after
            for (int j = 0; j < Kernel::kTaps; ++j) {
                long long idx = base + j;
                if (idx >= nn && cyclic) idx %= nn;
                const bool in = idx >= 0 && idx < nn;
                bs[j] = in ? s[idx] : 0.0;
                bc[j] = in ? c[idx] : 0.0;
            }
            xs = bs;
            xc = bc;
        }
        blend_dot(w0, w1, al, xs, xc, vs, vc);
        if (ds) {
            const double* d0 = &K.dw[static_cast<std::size_t>(r) * Kernel::kTaps];
            blend_dot(d0, d0 + Kernel::kTaps, al, xs, xc, *ds, *dc);
            *ds *= fs;
            *dc *= fs;
        }
    }
    double t_end() const { return cyclic ? std::numeric_limits<double>::infinity() : (static_cast<double>(n) - 1) / fs; }
};

struct Fit {
    // tau(m) = tau_c + (m - m_c) * (1 + kappa) / fs_rec
    double tau_c = 0, m_c = 0, kappa = 0;
    double gs = 1, os = 0, gc = 1, oc = 0;
    bool swap = false;        // the record's sin channel shows the played cos (and vice versa)
    double ssr = 0, srr = 0;  // residual and signal (about the offsets) sums of squares, both channels
    std::size_t n = 0;        // samples (pairs) fitted
    double var_tau = 0, var_kappa = 0;
    bool ok = false;
    double tau0() const { return tau_c - m_c * (1 + kappa) / fs_rec; }
    double fs_rec = 1;
};

std::string fmt(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.4g", v);
    return b;
}

std::size_t next_pow2(std::size_t n) {
    std::size_t p = 1;
    while (p < n) p <<= 1;
    return p;
}

class Aligner {
public:
    Aligner(const AlignInput& in, const AlignOptions& o)
        : in_(in), o_(o), p_{in.played_sin_v.data(), in.played_cos_v.data(), in.played_sin_v.size(), in.play_rate_hz, in.cyclic},
          M_(in.recorded_sin_v.size()), fs_(in.record_rate_hz) {}

    AlignResult run();

private:
    // Record indices [lo, hi) whose generator time lies inside the played signal (away from its
    // edges by the interpolator's half-width), for a fit f.
    void interior(const Fit& f, std::size_t& lo, std::size_t& hi) const {
        const double b = (1 + f.kappa) / fs_, a = f.tau0();
        const double t_lo = (kH + 1) / p_.fs, t_hi = p_.t_end() - (kH + 1) / p_.fs;
        const double m_lo = std::ceil((t_lo - a) / b);
        const double m_hi = std::isfinite(t_hi) ? std::floor((t_hi - a) / b) + 1 : static_cast<double>(M_);
        lo = static_cast<std::size_t>(std::clamp(m_lo, 0.0, static_cast<double>(M_)));
        hi = static_cast<std::size_t>(std::clamp(m_hi, static_cast<double>(lo), static_cast<double>(M_)));
    }
    // The model's played pair at generator time t, in the record's channel order.
    void model(const Fit& f, double t, double& vs, double& vc, double* ds = nullptr, double* dc = nullptr) const {
        p_.eval(t, vs, vc, ds, dc);
        if (f.swap) {
            std::swap(vs, vc);
            if (ds) std::swap(*ds, *dc);
        }
    }
    void gauss_newton(Fit& f, std::size_t lo, std::size_t hi, int max_iter, std::size_t max_samples) const;
    double sum_squares(const Fit& f, std::size_t lo, std::size_t hi, std::size_t stride, double* srr = nullptr, std::size_t* used = nullptr) const;
    void linear_fit(Fit& f, std::size_t lo, std::size_t hi, std::size_t stride) const;
    double decision_ssr(const Fit& f, std::size_t* used = nullptr) const;
    bool refine(Fit& f, int iters, std::size_t max_samples) const;
    std::size_t clean_record();

    const AlignInput& in_;
    const AlignOptions& o_;
    Played p_;
    std::vector<double> rsv_, rcv_;  // the record with outliers replaced by the channel's median
    std::vector<unsigned char> bad_; // 1: an outlier, left out of every sum
    const double* rs_ = nullptr;
    const double* rc_ = nullptr;
    std::size_t M_;
    double fs_;
};

// Outliers: a sample that is not finite or lies absurdly far from the rest (a glitch, a
// transfer error) would dominate every sum of squares and the FFT correlation; it is left out.
std::size_t Aligner::clean_record() {
    rsv_.assign(in_.recorded_sin_v.begin(), in_.recorded_sin_v.end());
    rcv_.assign(in_.recorded_cos_v.begin(), in_.recorded_cos_v.end());
    bad_.assign(M_, 0);
    for (auto* v : {&rsv_, &rcv_}) {
        std::vector<double> x;
        const std::size_t stride = std::max<std::size_t>(1, M_ / (1u << 20));
        for (std::size_t m = 0; m < M_; m += stride)
            if (std::isfinite((*v)[m])) x.push_back((*v)[m]);
        double med = 0, q = 0;
        if (!x.empty()) {
            auto mid = x.begin() + static_cast<std::ptrdiff_t>(x.size() / 2);
            std::nth_element(x.begin(), mid, x.end());
            med = *mid;
            for (auto& e : x) e = std::fabs(e - med);
            auto q90 = x.begin() + static_cast<std::ptrdiff_t>(std::min(x.size() - 1, x.size() * 9 / 10));
            std::nth_element(x.begin(), q90, x.end());
            q = *q90;
        }
        // A floor keeps a silent, quantised channel (all one code) from flagging its noise; no
        // input measures a megavolt, whatever share of such samples there is.
        const double lim = std::min(o_.outlier_factor * std::max(q, 1e-12 + 1e-9 * std::fabs(med)), 1e6);
        for (std::size_t m = 0; m < M_; ++m) {
            double& e = (*v)[m];
            if (!std::isfinite(e) || std::fabs(e - med) > lim) {
                bad_[m] = 1;
                e = med;
            }
        }
    }
    rs_ = rsv_.data();
    rc_ = rcv_.data();
    return static_cast<std::size_t>(std::count(bad_.begin(), bad_.end(), 1));
}

// Gains and offsets at fixed timing (closed-form least squares per channel; any sign).
void Aligner::linear_fit(Fit& f, std::size_t lo, std::size_t hi, std::size_t stride) const {
    double n = 0, sp[2] = {0, 0}, spp[2] = {0, 0}, sr[2] = {0, 0}, spr[2] = {0, 0};
    const double b = (1 + f.kappa) / fs_;
    for (std::size_t m = lo; m < hi; m += stride) {
        if (bad_[m]) continue;
        double vs, vc;
        model(f, f.tau_c + (static_cast<double>(m) - f.m_c) * b, vs, vc);
        const double v[2] = {vs, vc}, r[2] = {rs_[m], rc_[m]};
        n += 1;
        for (int ch = 0; ch < 2; ++ch) { sp[ch] += v[ch]; spp[ch] += v[ch] * v[ch]; sr[ch] += r[ch]; spr[ch] += v[ch] * r[ch]; }
    }
    if (n < 1) return;
    double g[2], off[2];
    for (int ch = 0; ch < 2; ++ch) {
        const double var = spp[ch] - sp[ch] * sp[ch] / n;
        g[ch] = var > 0 ? (spr[ch] - sp[ch] * sr[ch] / n) / var : 0.0;
        off[ch] = (sr[ch] - g[ch] * sp[ch]) / n;
    }
    f.gs = g[0]; f.os = off[0]; f.gc = g[1]; f.oc = off[1];
}

double Aligner::sum_squares(const Fit& f, std::size_t lo, std::size_t hi, std::size_t stride, double* srr, std::size_t* used) const {
    double ssr = 0, sig = 0;
    std::size_t n = 0;
    const double b = (1 + f.kappa) / fs_;
    for (std::size_t m = lo; m < hi; m += stride) {
        if (bad_[m]) continue;
        double vs, vc;
        model(f, f.tau_c + (static_cast<double>(m) - f.m_c) * b, vs, vc);
        const double es = rs_[m] - (f.gs * vs + f.os), ec = rc_[m] - (f.gc * vc + f.oc);
        ssr += es * es + ec * ec;
        ++n;
        if (srr) sig += (rs_[m] - f.os) * (rs_[m] - f.os) + (rc_[m] - f.oc) * (rc_[m] - f.oc);
    }
    if (srr) *srr = sig;
    if (used) *used = n;
    return ssr;
}

// Levenberg-damped Gauss-Newton on [tau_c, kappa, gs, os, gc, oc] over record samples [lo, hi)
// (every k-th one beyond max_samples).
void Aligner::gauss_newton(Fit& f, std::size_t lo, std::size_t hi, int max_iter, std::size_t max_samples) const {
    using Mat6 = Eigen::Matrix<double, 6, 6>;
    using Vec6 = Eigen::Matrix<double, 6, 1>;
    const std::size_t stride = std::max<std::size_t>(1, (hi - lo + max_samples - 1) / max_samples);
    // Re-centre the time axis on the window (decorrelates delay and clock ratio).
    const double mc = 0.5 * static_cast<double>(lo + hi - 1);
    f.tau_c += (mc - f.m_c) * (1 + f.kappa) / fs_;
    f.m_c = mc;
    double lambda = 1e-6;
    std::size_t used = 0;
    double ssr = sum_squares(f, lo, hi, stride, nullptr, &used);
    Mat6 JtJ;
    for (int it = 0; it < max_iter; ++it) {
        JtJ.setZero();
        Vec6 Jtr = Vec6::Zero();
        const double b = (1 + f.kappa) / fs_;
        for (std::size_t m = lo; m < hi; m += stride) {
            if (bad_[m]) continue;
            const double dm = (static_cast<double>(m) - mc) / fs_;
            double vs, vc, ds, dc;
            model(f, f.tau_c + (static_cast<double>(m) - mc) * b, vs, vc, &ds, &dc);
            const double es = rs_[m] - (f.gs * vs + f.os), ec = rc_[m] - (f.gc * vc + f.oc);
            Vec6 js, jc;
            js << f.gs * ds, f.gs * ds * dm, vs, 1, 0, 0;
            jc << f.gc * dc, f.gc * dc * dm, 0, 0, vc, 1;
            JtJ.selfadjointView<Eigen::Lower>().rankUpdate(js);
            JtJ.selfadjointView<Eigen::Lower>().rankUpdate(jc);
            Jtr += js * es + jc * ec;
        }
        JtJ = JtJ.selfadjointView<Eigen::Lower>();
        // Jacobi scaling keeps seconds, ppm and volts comparable.
        Vec6 sc;
        for (int i = 0; i < 6; ++i) sc[i] = JtJ(i, i) > 0 ? 1 / std::sqrt(JtJ(i, i)) : 1.0;
        const Mat6 A = sc.asDiagonal() * JtJ * sc.asDiagonal();
        const Vec6 g = sc.asDiagonal() * Jtr;
        bool improved = false;
        Vec6 step = Vec6::Zero();
        for (int tries = 0; tries < 12; ++tries) {
            Mat6 Ad = A;
            Ad.diagonal().array() += lambda;
            step = sc.asDiagonal() * Ad.ldlt().solve(g);
            Fit t = f;
            t.tau_c += step[0]; t.kappa += step[1]; t.gs += step[2]; t.os += step[3]; t.gc += step[4]; t.oc += step[5];
            const double s2 = sum_squares(t, lo, hi, stride);
            if (s2 <= ssr) {
                f = t;
                improved = ssr - s2 > 1e-14 * ssr;
                ssr = s2;
                lambda = std::max(lambda / 10, 1e-9);
                break;
            }
            lambda *= 10;
        }
        // Converged: the delay moved by less than 1e-7 sample over the window.
        const double span = static_cast<double>(hi - lo) / fs_;
        if (!improved || (std::fabs(step[0]) * fs_ < 1e-7 && std::fabs(step[1]) * span * fs_ < 1e-7)) break;
    }
    f.n = used;
    f.ssr = ssr;
    // Covariance sigma^2 (J^T J)^-1 at the solution (stride: the subset's own count).
    const double dof = std::max(1.0, 2.0 * static_cast<double>(f.n) - 6);
    const double s2 = ssr / dof;
    Eigen::Matrix<double, 6, 6> cov = JtJ.ldlt().solve(Eigen::Matrix<double, 6, 6>::Identity());
    f.var_tau = s2 * cov(0, 0);
    f.var_kappa = s2 * cov(1, 1);
    f.ok = std::isfinite(ssr) && std::isfinite(f.tau_c) && std::isfinite(f.kappa);
}

// Sum of squares over the whole record with the idle output outside the played span: what
// tells copies one period apart from each other (the onset and the end are where they differ).
double Aligner::decision_ssr(const Fit& f, std::size_t* used) const {
    return sum_squares(f, 0, M_, std::max<std::size_t>(1, M_ / (4 * o_.max_fit_samples)), nullptr, used);
}

// Gains and offsets re-solved (any sign) at f's timing, then Gauss-Newton over the interior;
// f's ssr, srr and n are those of every interior sample.
bool Aligner::refine(Fit& f, int iters, std::size_t max_samples) const {
    std::size_t lo, hi;
    interior(f, lo, hi);
    if (hi <= lo + 32) return false;
    linear_fit(f, lo, hi, std::max<std::size_t>(1, (hi - lo) / 8192));
    gauss_newton(f, lo, hi, iters, max_samples);
    if (!f.ok) return false;
    interior(f, lo, hi);
    if (hi <= lo + 32) return false;
    f.ssr = sum_squares(f, lo, hi, 1, &f.srr, &f.n);
    return std::isfinite(f.ssr) && f.n > 16;
}

// How a fit's wiring reads in a message.
std::string wiring(const Fit& f) {
    std::string w;
    if (f.swap) w = "sin and cos swapped";
    if (f.gs < 0 && f.gc < 0) w += std::string(w.empty() ? "" : ", ") + "both channels inverted";
    else if (f.gs < 0 || f.gc < 0) w += std::string(w.empty() ? "" : ", ") + "the " + (f.gs < 0 ? "sin" : "cos") + " channel inverted";
    return w.empty() ? "as wired" : w;
}

AlignResult Aligner::run() {
    AlignResult r;
    r.record_rate_hz = fs_;
    r.method = "outliers left out; coarse: least squares over integer lags against the played onset (FFT) on a grid of clock offsets, "
               "sin and cos as wired and swapped; fine: Gauss-Newton on delay, clock ratio, gain and offset per channel, played waveform "
               "Kaiser-sinc interpolated (24 taps a side); candidates (neighbouring periods, quarter periods, swapped and inverted "
               "wiring) compared on the whole record including the idle output";
    auto fail = [&](const std::string& why) {
        r.ok = false;
        r.error = why;
        return r;
    };
    if (in_.played_sin_v.size() != in_.played_cos_v.size() || in_.recorded_sin_v.size() != in_.recorded_cos_v.size())
        return fail("sin and cos have different lengths");
    if (!(p_.fs > 0) || !(fs_ > 0)) return fail("sample rates must be positive");
    if (p_.n < 16) return fail("too few samples played (" + std::to_string(p_.n) + ")");
    if (M_ < 64) return fail("too few samples recorded (" + std::to_string(M_) + ")");
    r.search_clock_offset_ppm = o_.search_clock_offset_ppm;

    // Samples per cycle of the played signal (zero crossings of sin about its mean), for the
    // coarse template's length and the clock-offset grid: an offset between grid points must not
    // smear the template by more than a quarter cycle.
    const std::size_t probe = std::min<std::size_t>(p_.n, 1u << 20);
    double mean = 0, mean_c = 0;
    for (std::size_t i = 0; i < probe; ++i) { mean += p_.s[i]; mean_c += p_.c[i]; }
    mean /= static_cast<double>(probe);
    mean_c /= static_cast<double>(probe);
    std::size_t crossings = 0;
    double ac = 0, acs = 0, acc = 0;
    double level = 0;
    for (std::size_t i = 0; i < probe; ++i) {
        acs += (p_.s[i] - mean) * (p_.s[i] - mean);
        acc += (p_.c[i] - mean_c) * (p_.c[i] - mean_c);
        level += mean * mean + mean_c * mean_c;
        if (i && (p_.s[i - 1] - mean < 0) != (p_.s[i] - mean < 0)) ++crossings;
    }
    ac = acs + acc;
    // Rounding leaves ~1e-32 of "variation" on a constant: relative to the level, not zero.
    ac = ac > 1e-20 * level ? ac : 0.0;
    if (!(ac > 0)) return fail("the played signal is constant: there is nothing to align on (a motion at rest)");
    r.outlier_samples = clean_record();
    if (static_cast<double>(r.outlier_samples) > o_.max_outlier_fraction * static_cast<double>(M_))
        return fail(std::to_string(r.outlier_samples) + " recorded samples (" + fmt(100.0 * static_cast<double>(r.outlier_samples) / static_cast<double>(M_)) +
                    " %) are not finite or lie beyond " + fmt(o_.outlier_factor) + " times the record's 90th percentile deviation (or 1e6 V); at most " +
                    fmt(100 * o_.max_outlier_fraction) + " % are left out: check the digitizer's range and transfer");
    // Peak amplitudes of the played channels (V), for the recorded amplitudes.
    const double amp_s = std::sqrt(2 * acs / static_cast<double>(probe)), amp_c = std::sqrt(2 * acc / static_cast<double>(probe));
    const double spc_play = crossings >= 2 ? 2.0 * static_cast<double>(probe) / static_cast<double>(crossings) : 0.0;
    const double spc_rec = spc_play > 0 ? spc_play * fs_ / p_.fs : 1e12;
    constexpr double kDesignPpm = 200e-6;  // the template's length: this offset smears it by a quarter cycle
    std::size_t K = static_cast<std::size_t>(std::clamp(0.25 * spc_rec / kDesignPpm, 2048.0, 65536.0));
    const double played_rec_len = p_.cyclic ? 1e18 : static_cast<double>(p_.n) * fs_ / p_.fs;
    K = std::min<std::size_t>({K, static_cast<std::size_t>(played_rec_len), M_ / 2});
    const std::size_t Z = K / 4;  // idle samples ahead of the onset in the template
    const std::size_t T = Z + K;
    // Clock-offset grid: step 2 e with e the offset that drifts a quarter cycle over the template.
    const double e_tol = 0.25 * spc_rec / static_cast<double>(K);
    const double search = std::max(0.0, o_.search_clock_offset_ppm) * 1e-6;
    const int ngrid = e_tol >= search ? 0 : static_cast<int>(std::ceil(search / (2 * e_tol)));
    const double step_k = ngrid > 0 ? search / ngrid : 0.0;
    r.search_step_ppm = step_k * 1e6;

    // Onset lags L (record index of the generator's sample 0) searched: the template may hang
    // out of the record by half its signal part at either end.
    const long long Lmin = -static_cast<long long>(K / 2);
    const long long Lmax = std::min<long long>(static_cast<long long>(M_) - static_cast<long long>(K / 2), 1ll << 20);
    if (Lmax < Lmin) return fail("the record is too short for the played onset");
    const long long smin = Lmin - static_cast<long long>(Z);
    const std::size_t nl = static_cast<std::size_t>(Lmax - Lmin + 1);
    const std::size_t F = next_pow2(nl + T);
    Eigen::FFT<double> fft;
    // The record's spectra, once (windowed from smin).
    std::vector<std::complex<double>> X[2];
    std::vector<double> pr[2], pr2[2];
    for (int ch = 0; ch < 2; ++ch) {
        const double* rec = ch == 0 ? rs_ : rc_;
        std::vector<std::complex<double>> A(F);
        for (std::size_t i = 0; i < F; ++i) {
            const long long m = smin + static_cast<long long>(i);
            A[i] = (m >= 0 && m < static_cast<long long>(M_)) ? rec[m] : 0.0;
        }
        fft.fwd(X[ch], A);
        pr[ch].assign(M_ + 1, 0.0); pr2[ch].assign(M_ + 1, 0.0);
        for (std::size_t m = 0; m < M_; ++m) { pr[ch][m + 1] = pr[ch][m] + rec[m]; pr2[ch][m + 1] = pr2[ch][m] + rec[m] * rec[m]; }
    }
    struct Coarse {
        double score = -std::numeric_limits<double>::infinity();
        double corr = -1, rho[2] = {0, 0};
        long long L = 0;
        double frac = 0, kappa = 0;
        bool swap = false;
    };
    std::vector<Coarse> peaks;
    Coarse top;
    std::vector<double> ts(T), tc(T), sc_score(nl), sc_corr(nl);
    std::vector<std::vector<double>> cc(4, std::vector<double>(nl));  // rec s x tmpl s, rec c x tmpl c, rec s x tmpl c, rec c x tmpl s
    for (int gi = -ngrid; gi <= ngrid; ++gi) {
        const double kg = gi * step_k;
        // Template at the record's rate on a generator clock kg fast: idle, then the played onset.
        std::fill(ts.begin(), ts.begin() + static_cast<std::ptrdiff_t>(Z), 0.0);
        std::fill(tc.begin(), tc.begin() + static_cast<std::ptrdiff_t>(Z), 0.0);
        for (std::size_t j = 0; j < K; ++j) p_.eval(static_cast<double>(j) * (1 + kg) / fs_, ts[Z + j], tc[Z + j]);
        std::vector<double> pt[2], pt2[2];
        for (int ch = 0; ch < 2; ++ch) {
            const std::vector<double>& tt = ch == 0 ? ts : tc;
            pt[ch].assign(T + 1, 0.0); pt2[ch].assign(T + 1, 0.0);
            for (std::size_t j = 0; j < T; ++j) { pt[ch][j + 1] = pt[ch][j] + tt[j]; pt2[ch][j + 1] = pt2[ch][j] + tt[j] * tt[j]; }
        }
        {
            std::vector<std::complex<double>> B(F), Y[2], Cc(F), out;
            for (int t = 0; t < 2; ++t) {
                const std::vector<double>& tt = t == 0 ? ts : tc;
                for (std::size_t i = 0; i < F; ++i) B[i] = i < T ? tt[i] : 0.0;
                fft.fwd(Y[t], B);
            }
            const int pairs[4][2] = {{0, 0}, {1, 1}, {0, 1}, {1, 0}};  // {record channel, template channel}
            for (int k = 0; k < 4; ++k) {
                for (std::size_t i = 0; i < F; ++i) Cc[i] = X[pairs[k][0]][i] * std::conj(Y[pairs[k][1]][i]);
                fft.inv(out, Cc);
                for (std::size_t d = 0; d < nl; ++d) cc[static_cast<std::size_t>(k)][d] = out[d].real();
            }
        }
        for (int sw = 0; sw < 2; ++sw) {
            // Per record channel: the explained and total sums of squares (V^2) with the best gain
            // (either sign) and offset; the lag's score is explained minus unexplained, which
            // prefers a full overlap of the template (idle part included) to a partial one.
            auto stats = [&](std::size_t d, double* rho_ch, double* corr) {
                const long long s = smin + static_cast<long long>(d);
                const long long j0 = std::max<long long>(0, -s), j1 = std::min<long long>(static_cast<long long>(T), static_cast<long long>(M_) - s);
                if (j1 - j0 < 16) return -std::numeric_limits<double>::infinity();
                const double n = static_cast<double>(j1 - j0);
                double expl = 0, tot = 0;
                for (int ch = 0; ch < 2; ++ch) {
                    const int tch = sw ? 1 - ch : ch;
                    const double sr = pr[ch][s + j1] - pr[ch][s + j0], srr = pr2[ch][s + j1] - pr2[ch][s + j0] - sr * sr / n;
                    const double st = pt[tch][j1] - pt[tch][j0], stt = pt2[tch][j1] - pt2[tch][j0] - st * st / n;
                    const double srt = cc[static_cast<std::size_t>(sw ? 2 + ch : ch)][d] - sr * st / n;
                    if (stt > 0) expl += srt * srt / stt;
                    tot += std::max(srr, 0.0);
                    if (rho_ch) rho_ch[ch] = stt > 0 && srr > 0 ? srt / std::sqrt(stt * srr) : 0.0;
                }
                if (corr) *corr = tot > 0 ? std::sqrt(std::min(1.0, expl / tot)) : 0.0;
                return 2 * expl - tot;
            };
            for (std::size_t d = 0; d < nl; ++d) sc_score[d] = stats(d, nullptr, nullptr);
            for (std::size_t d = 0; d < nl; ++d) {
                const double e = sc_score[d];
                if (!std::isfinite(e)) continue;
                if ((d > 0 && sc_score[d - 1] > e) || (d + 1 < nl && sc_score[d + 1] >= e)) continue;
                Coarse c;
                c.score = e;
                c.L = Lmin + static_cast<long long>(d);
                c.kappa = kg;
                c.swap = sw != 0;
                stats(d, c.rho, &c.corr);
                // Sub-sample start from a parabola through the score.
                if (d > 0 && d + 1 < nl) {
                    const double y0 = sc_score[d - 1], y2 = sc_score[d + 1], den = y0 - 2 * e + y2;
                    if (den < 0) c.frac = std::clamp(0.5 * (y0 - y2) / den, -0.5, 0.5);
                }
                peaks.push_back(c);
                if (c.score > top.score) top = c;
            }
        }
    }
    r.correlation = top.corr;
    r.correlation_sin = top.rho[0];
    r.correlation_cos = top.rho[1];
    r.coarse_clock_offset_ppm = top.kappa * 1e6;
    if (!(r.correlation >= o_.min_correlation))
        return fail("no correlation between the played and the recorded signals (best normalised correlation " + fmt(r.correlation) + " < " +
                    fmt(o_.min_correlation) + "; per channel at that lag: sin " + fmt(top.rho[0]) + ", cos " + fmt(top.rho[1]) +
                    ", searched over clock offsets within +-" + fmt(o_.search_clock_offset_ppm) +
                    " ppm and sin/cos as wired and swapped): check that the input records the generator's outputs");

    // Candidates: the best local maxima of the coarse score over all grid points and both
    // wirings (periodic signals give one per period; the onset ranks the right one first, the
    // decision below checks it).
    std::sort(peaks.begin(), peaks.end(), [](const Coarse& a, const Coarse& b) { return a.score > b.score; });
    std::vector<Coarse> cand;
    for (const auto& c : peaks) {
        if (cand.size() >= 6) break;
        bool dup = false;
        for (const auto& d : cand) dup |= d.swap == c.swap && std::llabs(d.L - c.L) < 2;
        if (!dup) cand.push_back(c);
    }

    std::vector<Fit> fits;
    std::vector<double> dec;
    auto add = [&](const Fit& f) {
        for (const auto& g : fits)
            if (g.swap == f.swap && std::fabs(g.tau0() - f.tau0()) * fs_ < 0.25) return false;
        fits.push_back(f);
        dec.push_back(decision_ssr(f));
        return true;
    };
    Fit first;
    for (std::size_t ci = 0; ci < cand.size(); ++ci) {
        const double L = static_cast<double>(cand[ci].L) + cand[ci].frac;
        Fit f;
        f.fs_rec = fs_;
        if (ci == 0) {
            // Window doubling from the onset: the clock ratio is learned before it can slip a cycle.
            f.kappa = cand[ci].kappa;
            f.swap = cand[ci].swap;
            f.m_c = std::max(0.0, L);
            f.tau_c = (f.m_c - L) * (1 + f.kappa) / fs_;
            std::size_t lo, hi;
            interior(f, lo, hi);
            if (hi <= lo + 32) return fail("the played and recorded signals overlap by too few samples");
            std::size_t w = std::min(hi - lo, K);
            linear_fit(f, lo, lo + w, 1);
            for (;;) {
                gauss_newton(f, lo, lo + w, 30, o_.max_fit_samples);
                if (!f.ok) break;
                if (lo + w >= hi) break;
                w = std::min(hi - lo, 2 * w);
                interior(f, lo, hi);
                w = std::min(w, hi > lo ? hi - lo : 0);
                if (w < 32) break;
            }
            if (!f.ok || !refine(f, 2, o_.max_fit_samples)) return fail("the fit did not converge");
            first = f;
        } else {
            // Another onset: the first fit's clock ratio, shifted, with its own wiring.
            f = first;
            f.swap = cand[ci].swap;
            const double L0 = -first.tau0() * fs_ / (1 + first.kappa);
            f.tau_c = first.tau_c - (L - L0) * (1 + first.kappa) / fs_;
            if (!refine(f, 10, 8192)) continue;
        }
        add(f);
    }
    auto best_index = [&]() {
        std::size_t b = 0;
        for (std::size_t i = 1; i < fits.size(); ++i)
            if (dec[i] < dec[b]) b = i;
        return b;
    };
    std::size_t bi = best_index();
    // Wiring faults that a constant speed turns into a phase shift (both inverted: half a cycle;
    // swapped with one inverted: a quarter) fit the inside of the record as well as the right
    // wiring at another delay: quarter-period shifts of the best, as wired and swapped, signs
    // free, are fitted too, and the output's start and end in the record tell them apart.
    const double period_gen_s = spc_play > 0 ? spc_play / p_.fs : 0.0;
    if (period_gen_s > 0) {
        const Fit b0 = fits[bi];
        for (int sw = 0; sw < 2; ++sw)
            for (int q = -3; q <= 3; ++q) {
                if (q == 0 && (sw != 0) == b0.swap) continue;
                Fit f = b0;
                f.swap = (sw != 0) != b0.swap;
                f.tau_c += q * period_gen_s / 4;
                if (refine(f, 10, 8192)) add(f);
            }
        bi = best_index();
    }
    // The right onset may lie beyond the candidates: step from the best by whole periods while
    // that fits better.
    for (int dir = -1; period_gen_s > 0 && dir <= 1; dir += 2) {
        for (int step = 0; step < 64; ++step) {
            Fit f = fits[bi];
            f.tau_c += dir * period_gen_s;
            if (!refine(f, 10, 8192)) break;
            const std::size_t before = fits.size();
            if (!add(f)) break;
            if (dec[before] >= dec[bi]) break;
            bi = before;
        }
    }
    // The chosen fit over every interior sample (its covariance from the last iteration).
    Fit f = fits[bi];
    {
        std::size_t lo, hi;
        interior(f, lo, hi);
        gauss_newton(f, lo, hi, 30, o_.max_fit_samples);
        if (!f.ok) return fail("the fit did not converge");
        interior(f, lo, hi);
        if (hi <= lo + 32) return fail("the played and recorded signals overlap by too few samples");
        f.ssr = sum_squares(f, lo, hi, 1, &f.srr, &f.n);
        fits[bi] = f;
        dec[bi] = decision_ssr(f);
    }
    r.candidates = fits.size();
    r.tau0_s = f.tau0();
    r.clock_offset_ppm = f.kappa * 1e6;
    r.delay_s = -r.tau0_s / (1 + f.kappa);
    r.swapped = f.swap;
    r.sin = {f.gs, f.os, std::fabs(f.gs) * (f.swap ? amp_c : amp_s)};
    r.cos = {f.gc, f.oc, std::fabs(f.gc) * (f.swap ? amp_s : amp_c)};
    r.fitted_samples = f.n;
    r.residual_rms_v = std::sqrt(f.ssr / (2.0 * static_cast<double>(std::max<std::size_t>(f.n, 1))));
    r.signal_rms_v = std::sqrt(f.srr / (2.0 * static_cast<double>(std::max<std::size_t>(f.n, 1))));
    r.residual_relative = r.signal_rms_v > 0 ? r.residual_rms_v / r.signal_rms_v : std::numeric_limits<double>::infinity();
    {
        std::size_t used = 0;
        const double d = decision_ssr(f, &used);
        r.record_residual_rms_v = std::sqrt(d / (2.0 * static_cast<double>(std::max<std::size_t>(used, 1))));
    }
    r.delay_std_s = std::sqrt(std::max(0.0, f.var_tau));
    r.clock_offset_std_ppm = std::sqrt(std::max(0.0, f.var_kappa)) * 1e6;
    r.ambiguity_z = std::numeric_limits<double>::infinity();
    std::size_t alt = bi;
    for (std::size_t i = 0; i < fits.size(); ++i) {
        if (i == bi) continue;
        const double dssr = std::max(0.0, dec[i] - dec[bi]);
        // The difference of two sums of squares has standard deviation 2 sigma sqrt(dssr).
        const double z = r.residual_rms_v > 0 ? std::sqrt(dssr) / (2 * r.residual_rms_v) : std::numeric_limits<double>::infinity();
        if (z < r.ambiguity_z) {
            r.ambiguity_z = z;
            r.alternative_shift_s = fits[i].tau0() - f.tau0();
            alt = i;
        }
    }
    // Confidence (docs/alignment.md "When alignment is refused"), most basic cause first.
    {
        const double weak = std::min(r.sin.amplitude_v, r.cos.amplitude_v), strong = std::max(r.sin.amplitude_v, r.cos.amplitude_v);
        const double lim = std::max(o_.min_amplitude_v, o_.min_amplitude_ratio * strong);
        if (!(weak >= lim)) {
            const bool sin_flat = r.sin.amplitude_v <= r.cos.amplitude_v;
            return fail(std::string("the ") + (sin_flat ? "sin" : "cos") + " channel is flat: it shows " + fmt(weak) + " V of the played signal (peak), below " +
                        fmt(lim) + " V (" + fmt(o_.min_amplitude_ratio) + " of the " + (sin_flat ? "cos" : "sin") + " channel's " + fmt(strong) +
                        " V, at least " + fmt(o_.min_amplitude_v) + " V): disconnected, shorted or not recording");
        }
    }
    if (std::fabs(r.clock_offset_ppm) > o_.max_clock_offset_ppm)
        return fail("the clock offset " + fmt(r.clock_offset_ppm) + " ppm is out of the supported range (+-" + fmt(o_.max_clock_offset_ppm) +
                    " ppm): the generator's and the digitizer's clocks (or their sample rates) differ by more than that");
    if (!(r.residual_relative <= o_.max_residual_relative))
        return fail("the fit leaves a residual of " + fmt(r.residual_rms_v) + " V rms, " + fmt(r.residual_relative) + " of the signal (limit " +
                    fmt(o_.max_residual_relative) + "): the recorded signal is not the played one up to delay, clock offset, gain and offset "
                    "(distortion, bandwidth, a wrong channel, or clipping)");
    if (!(r.record_residual_rms_v <= o_.max_record_residual_factor * r.residual_rms_v + o_.record_residual_allowance * r.signal_rms_v))
        return fail("the whole record fits worse than the played span: " + fmt(r.record_residual_rms_v) + " V rms against " + fmt(r.residual_rms_v) +
                    " V inside it: the output does not start or stop in the record where the fit puts it (the best fit, delay " + fmt(r.delay_s) +
                    " s, is not the right one, or the output was interrupted)");
    if (r.ambiguity_z < o_.min_ambiguity_z) {
        const Fit& a = fits[alt];
        std::string what = "shifting the delay by " + fmt(r.alternative_shift_s) + " s";
        if (a.swap != f.swap || (a.gs < 0) != (f.gs < 0) || (a.gc < 0) != (f.gc < 0)) what += " with " + wiring(a) + " (not " + wiring(f) + ")";
        return fail("ambiguous delay: " + what + " fits the record almost as well (" + fmt(r.ambiguity_z) + " standard deviations apart, " +
                    fmt(o_.min_ambiguity_z) + " needed): the signal repeats and the record does not show where the output started or stopped "
                    "(the record must start before the output)");
    }
    if (f.swap || f.gs < 0 || f.gc < 0)
        return fail("the input is miswired: " + wiring(f) + " (gains: sin " + fmt(f.gs) + ", cos " + fmt(f.gc) +
                    "; the fit as wired is " + fmt(r.ambiguity_z) + " standard deviations worse or more, told apart by where the output starts "
                    "and stops): connect the generator's sin to the input's sin and cos to cos, same polarity");
    if (r.delay_std_s * fs_ > o_.max_delay_std_samples)
        return fail("the delay is uncertain by " + fmt(r.delay_std_s * fs_) + " samples (standard error; limit " + fmt(o_.max_delay_std_samples) + ")");
    r.ok = true;
    return r;
}

}  // namespace

double played_value(std::span<const double> played_v, double rate_hz, bool cyclic, double t_s) {
    Played p{played_v.data(), played_v.data(), played_v.size(), rate_hz, cyclic};
    double vs, vc;
    p.eval(t_s, vs, vc);
    return vs;
}

AlignResult align(const AlignInput& in, const AlignOptions& o) { return Aligner(in, o).run(); }

void to_json(nlohmann::json& j, const AlignResult& r) {
    auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); };
    j = {{"ok", r.ok},
         {"delay_s", num(r.delay_s)},
         {"clock_offset_ppm", num(r.clock_offset_ppm)},
         {"tau0_s", num(r.tau0_s)},
         {"channels", {{"sin", {{"gain", num(r.sin.gain)}, {"offset_v", num(r.sin.offset_v)}, {"amplitude_v", num(r.sin.amplitude_v)}}},
                       {"cos", {{"gain", num(r.cos.gain)}, {"offset_v", num(r.cos.offset_v)}, {"amplitude_v", num(r.cos.amplitude_v)}}}}},
         {"swapped", r.swapped},
         {"residual_rms_v", num(r.residual_rms_v)},
         {"signal_rms_v", num(r.signal_rms_v)},
         {"residual_relative", num(r.residual_relative)},
         {"record_residual_rms_v", num(r.record_residual_rms_v)},
         {"outlier_samples", r.outlier_samples},
         {"search", {{"clock_offset_ppm", num(r.search_clock_offset_ppm)}, {"step_ppm", num(r.search_step_ppm)}, {"coarse_clock_offset_ppm", num(r.coarse_clock_offset_ppm)}}},
         {"confidence", {{"correlation", num(r.correlation)}, {"correlation_sin", num(r.correlation_sin)}, {"correlation_cos", num(r.correlation_cos)},
                         {"delay_std_s", num(r.delay_std_s)}, {"clock_offset_std_ppm", num(r.clock_offset_std_ppm)},
                         {"ambiguity_z", num(r.ambiguity_z)}, {"alternative_shift_s", r.candidates > 1 ? num(r.alternative_shift_s) : nlohmann::json()},
                         {"candidates", r.candidates}}},
         {"fitted_samples", r.fitted_samples},
         {"method", r.method}};
    j["error"] = r.ok ? nlohmann::json() : nlohmann::json(r.error);
}

}  // namespace fringe
