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
#include "align.hpp"

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

constexpr double kPi = 3.14159265358979323846;
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
    double ssr = 0, srr = 0;  // residual and signal (about the offsets) sums of squares, both channels
    std::size_t n = 0;        // samples (pairs) fitted
    double var_tau = 0, var_kappa = 0;
    bool ok = false;
    double tau0() const { return tau_c - m_c * (1 + kappa) / fs_rec; }
    double fs_rec = 1;
};

class Aligner {
public:
    Aligner(const AlignInput& in, const AlignOptions& o)
        : in_(in), o_(o), p_{in.played_sin_v.data(), in.played_cos_v.data(), in.played_sin_v.size(), in.play_rate_hz, in.cyclic},
          rs_(in.recorded_sin_v.data()), rc_(in.recorded_cos_v.data()), M_(in.recorded_sin_v.size()), fs_(in.record_rate_hz) {}

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
    void gauss_newton(Fit& f, std::size_t lo, std::size_t hi, int max_iter) const;
    double sum_squares(const Fit& f, std::size_t lo, std::size_t hi, std::size_t stride, double* srr = nullptr) const;
    void linear_fit(Fit& f, std::size_t lo, std::size_t hi, std::size_t stride) const;
    double decision_ssr(const Fit& f) const;

    const AlignInput& in_;
    const AlignOptions& o_;
    Played p_;
    const double* rs_;
    const double* rc_;
    std::size_t M_;
    double fs_;
};

// Gains and offsets at fixed timing (closed-form least squares per channel).
void Aligner::linear_fit(Fit& f, std::size_t lo, std::size_t hi, std::size_t stride) const {
    double n = 0, sp[2] = {0, 0}, spp[2] = {0, 0}, sr[2] = {0, 0}, spr[2] = {0, 0};
    const double b = (1 + f.kappa) / fs_;
    for (std::size_t m = lo; m < hi; m += stride) {
        double vs, vc;
        p_.eval(f.tau_c + (static_cast<double>(m) - f.m_c) * b, vs, vc);
        const double v[2] = {vs, vc}, r[2] = {rs_[m], rc_[m]};
        n += 1;
        for (int ch = 0; ch < 2; ++ch) { sp[ch] += v[ch]; spp[ch] += v[ch] * v[ch]; sr[ch] += r[ch]; spr[ch] += v[ch] * r[ch]; }
    }
    double g[2], off[2];
    for (int ch = 0; ch < 2; ++ch) {
        const double var = spp[ch] - sp[ch] * sp[ch] / n;
        g[ch] = var > 0 ? (spr[ch] - sp[ch] * sr[ch] / n) / var : 0.0;
        off[ch] = (sr[ch] - g[ch] * sp[ch]) / n;
    }
    f.gs = g[0]; f.os = off[0]; f.gc = g[1]; f.oc = off[1];
}

double Aligner::sum_squares(const Fit& f, std::size_t lo, std::size_t hi, std::size_t stride, double* srr) const {
    double ssr = 0, sig = 0;
    const double b = (1 + f.kappa) / fs_;
    for (std::size_t m = lo; m < hi; m += stride) {
        double vs, vc;
        p_.eval(f.tau_c + (static_cast<double>(m) - f.m_c) * b, vs, vc);
        const double es = rs_[m] - (f.gs * vs + f.os), ec = rc_[m] - (f.gc * vc + f.oc);
        ssr += es * es + ec * ec;
        if (srr) sig += (rs_[m] - f.os) * (rs_[m] - f.os) + (rc_[m] - f.oc) * (rc_[m] - f.oc);
    }
    if (srr) *srr = sig;
    return ssr;
}

// Levenberg-damped Gauss-Newton on [tau_c, kappa, gs, os, gc, oc] over record samples [lo, hi).
void Aligner::gauss_newton(Fit& f, std::size_t lo, std::size_t hi, int max_iter) const {
    using Mat6 = Eigen::Matrix<double, 6, 6>;
    using Vec6 = Eigen::Matrix<double, 6, 1>;
    const std::size_t stride = std::max<std::size_t>(1, (hi - lo + o_.max_fit_samples - 1) / o_.max_fit_samples);
    // Re-centre the time axis on the window (decorrelates delay and clock ratio).
    const double mc = 0.5 * static_cast<double>(lo + hi - 1);
    f.tau_c += (mc - f.m_c) * (1 + f.kappa) / fs_;
    f.m_c = mc;
    double lambda = 1e-6;
    double ssr = sum_squares(f, lo, hi, stride);
    Mat6 JtJ;
    for (int it = 0; it < max_iter; ++it) {
        JtJ.setZero();
        Vec6 Jtr = Vec6::Zero();
        const double b = (1 + f.kappa) / fs_;
        for (std::size_t m = lo; m < hi; m += stride) {
            const double dm = (static_cast<double>(m) - mc) / fs_;
            double vs, vc, ds, dc;
            p_.eval(f.tau_c + (static_cast<double>(m) - mc) * b, vs, vc, &ds, &dc);
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
    f.n = (hi - lo + stride - 1) / stride;
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
double Aligner::decision_ssr(const Fit& f) const { return sum_squares(f, 0, M_, std::max<std::size_t>(1, M_ / (4 * o_.max_fit_samples))); }

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

AlignResult Aligner::run() {
    AlignResult r;
    r.record_rate_hz = fs_;
    r.method = "coarse: least squares over integer lags against the played onset (FFT); fine: Gauss-Newton on delay, clock ratio, "
               "gain and offset per channel, played waveform Kaiser-sinc interpolated (24 taps a side); candidates compared on the "
               "whole record including the idle output";
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

    // Samples per cycle of the played signal (zero crossings of sin about its mean), for the
    // coarse template's length: a clock offset must not smear it by more than a quarter cycle.
    const std::size_t probe = std::min<std::size_t>(p_.n, 1u << 20);
    double mean = 0, mean_c = 0;
    for (std::size_t i = 0; i < probe; ++i) { mean += p_.s[i]; mean_c += p_.c[i]; }
    mean /= static_cast<double>(probe);
    mean_c /= static_cast<double>(probe);
    std::size_t crossings = 0;
    double ac = 0;
    double level = 0;
    for (std::size_t i = 0; i < probe; ++i) {
        ac += (p_.s[i] - mean) * (p_.s[i] - mean) + (p_.c[i] - mean_c) * (p_.c[i] - mean_c);
        level += mean * mean + mean_c * mean_c;
        if (i && (p_.s[i - 1] - mean < 0) != (p_.s[i] - mean < 0)) ++crossings;
    }
    // Rounding leaves ~1e-32 of "variation" on a constant: relative to the level, not zero.
    ac = ac > 1e-20 * level ? ac : 0.0;
    if (!(ac > 0)) return fail("the played signal is constant: there is nothing to align on (a motion at rest)");
    const double spc_rec = crossings >= 2 ? 2.0 * static_cast<double>(probe) / static_cast<double>(crossings) * fs_ / p_.fs : 1e12;
    constexpr double kDesignPpm = 200e-6;  // clock offsets the coarse template tolerates by construction
    std::size_t K = static_cast<std::size_t>(std::clamp(0.25 * spc_rec / kDesignPpm, 2048.0, 65536.0));
    const double played_rec_len = p_.cyclic ? 1e18 : static_cast<double>(p_.n) * fs_ / p_.fs;
    K = std::min<std::size_t>({K, static_cast<std::size_t>(played_rec_len), M_ / 2});
    const std::size_t Z = K / 4;  // idle samples ahead of the onset in the template
    const std::size_t T = Z + K;

    // Template at the record's rate: idle, then the played onset.
    std::vector<double> ts(T, 0.0), tc(T, 0.0);
    for (std::size_t j = 0; j < K; ++j) p_.eval(static_cast<double>(j) / fs_, ts[Z + j], tc[Z + j]);
    // Onset lags L (record index of the generator's sample 0) searched: the template may hang
    // out of the record by half its signal part at either end.
    const long long Lmin = -static_cast<long long>(K / 2);
    const long long Lmax = std::min<long long>(static_cast<long long>(M_) - static_cast<long long>(K / 2), 1ll << 20);
    if (Lmax < Lmin) return fail("the record is too short for the played onset");
    const long long smin = Lmin - static_cast<long long>(Z);
    const std::size_t nl = static_cast<std::size_t>(Lmax - Lmin + 1);
    const std::size_t F = next_pow2(nl + T);
    Eigen::FFT<double> fft;
    std::vector<std::vector<double>> c(2, std::vector<double>(nl));
    {
        std::vector<std::complex<double>> A(F), B(F), X, Y, Cc(F), out;
        for (int ch = 0; ch < 2; ++ch) {
            const double* rec = ch == 0 ? rs_ : rc_;
            const std::vector<double>& tt = ch == 0 ? ts : tc;
            for (std::size_t i = 0; i < F; ++i) {
                const long long m = smin + static_cast<long long>(i);
                A[i] = (m >= 0 && m < static_cast<long long>(M_)) ? rec[m] : 0.0;
                B[i] = i < T ? tt[i] : 0.0;
            }
            fft.fwd(X, A);
            fft.fwd(Y, B);
            for (std::size_t i = 0; i < F; ++i) Cc[i] = X[i] * std::conj(Y[i]);
            fft.inv(out, Cc);
            for (std::size_t d = 0; d < nl; ++d) c[ch][d] = out[d].real();
        }
    }
    // Prefix sums for the per-lag centred statistics.
    std::vector<double> pr[2], pr2[2], pt[2], pt2[2];
    for (int ch = 0; ch < 2; ++ch) {
        const double* rec = ch == 0 ? rs_ : rc_;
        const std::vector<double>& tt = ch == 0 ? ts : tc;
        pr[ch].assign(M_ + 1, 0.0); pr2[ch].assign(M_ + 1, 0.0);
        for (std::size_t m = 0; m < M_; ++m) { pr[ch][m + 1] = pr[ch][m] + rec[m]; pr2[ch][m + 1] = pr2[ch][m] + rec[m] * rec[m]; }
        pt[ch].assign(T + 1, 0.0); pt2[ch].assign(T + 1, 0.0);
        for (std::size_t j = 0; j < T; ++j) { pt[ch][j + 1] = pt[ch][j] + tt[j]; pt2[ch][j + 1] = pt2[ch][j] + tt[j] * tt[j]; }
    }
    // Explained share of the window's variance with the best gain and offset per channel
    // (signed: an inverted channel counts against the lag).
    std::vector<double> expl(nl, -1.0);
    auto stats = [&](std::size_t d, double* rho_ch) {
        const long long s = smin + static_cast<long long>(d);
        const long long j0 = std::max<long long>(0, -s), j1 = std::min<long long>(static_cast<long long>(T), static_cast<long long>(M_) - s);
        if (j1 - j0 < 16) return -1.0;
        const double n = static_cast<double>(j1 - j0);
        double num = 0, den = 0;
        for (int ch = 0; ch < 2; ++ch) {
            const double sr = pr[ch][s + j1] - pr[ch][s + j0], srr = pr2[ch][s + j1] - pr2[ch][s + j0] - sr * sr / n;
            const double st = pt[ch][j1] - pt[ch][j0], stt = pt2[ch][j1] - pt2[ch][j0] - st * st / n;
            const double srt = c[ch][d] - sr * st / n;
            if (stt > 0) num += srt * std::fabs(srt) / stt;
            den += std::max(srr, 0.0);
            if (rho_ch) rho_ch[ch] = stt > 0 && srr > 0 ? srt / std::sqrt(stt * srr) : 0.0;
        }
        return den > 0 ? num / den : -1.0;
    };
    for (std::size_t d = 0; d < nl; ++d) expl[d] = stats(d, nullptr);
    std::size_t best = 0;
    for (std::size_t d = 1; d < nl; ++d)
        if (expl[d] > expl[best]) best = d;
    double rho_ch[2] = {0, 0};
    stats(best, rho_ch);
    r.correlation = expl[best] > 0 ? std::sqrt(expl[best]) : -std::sqrt(-expl[best]);
    r.correlation_sin = rho_ch[0];
    r.correlation_cos = rho_ch[1];
    if (r.correlation < o_.min_correlation)
        return fail("no correlation between the played and the recorded signals (best normalised correlation " + fmt(r.correlation) +
                    " < " + fmt(o_.min_correlation) + "; per channel at that lag: sin " + fmt(rho_ch[0]) + ", cos " + fmt(rho_ch[1]) +
                    "): check that the input records the generator's sin and cos, in that order and not inverted");

    // Candidates: local maxima of the coarse statistic, best first (periodic signals give one
    // per period; the onset ranks the right one first, the decision below checks it).
    std::vector<std::size_t> cand;
    for (std::size_t d = 0; d < nl; ++d) {
        const double e = expl[d];
        if (e < 0.5 * expl[best]) continue;
        if ((d > 0 && expl[d - 1] > e) || (d + 1 < nl && expl[d + 1] >= e)) continue;
        cand.push_back(d);
    }
    std::sort(cand.begin(), cand.end(), [&](std::size_t a, std::size_t b) { return expl[a] > expl[b]; });
    if (cand.size() > 6) cand.resize(6);

    std::vector<Fit> fits;
    Fit first;
    for (std::size_t ci = 0; ci < cand.size(); ++ci) {
        const std::size_t d = cand[ci];
        // Sub-sample start from a parabola through the statistic.
        double frac = 0;
        if (d > 0 && d + 1 < nl) {
            const double y0 = expl[d - 1], y1 = expl[d], y2 = expl[d + 1], den = y0 - 2 * y1 + y2;
            if (den < 0) frac = std::clamp(0.5 * (y0 - y2) / den, -0.5, 0.5);
        }
        const double L = static_cast<double>(Lmin + static_cast<long long>(d)) + frac;
        Fit f;
        f.fs_rec = fs_;
        if (ci == 0) {
            // Window doubling from the onset: the clock ratio is learned before it can slip a cycle.
            f.kappa = 0;
            f.m_c = std::max(0.0, L);
            f.tau_c = (f.m_c - L) / fs_;
            std::size_t lo, hi;
            interior(f, lo, hi);
            if (hi <= lo + 32) return fail("the played and recorded signals overlap by too few samples");
            std::size_t w = std::min(hi - lo, K);
            linear_fit(f, lo, lo + w, 1);
            for (;;) {
                gauss_newton(f, lo, lo + w, 30);
                if (!f.ok) break;
                if (lo + w >= hi) break;
                w = std::min(hi - lo, 2 * w);
                interior(f, lo, hi);
                w = std::min(w, hi > lo ? hi - lo : 0);
                if (w < 32) break;
            }
            if (!f.ok) return fail("the fit did not converge");
            first = f;
        } else {
            // Another onset: the first fit's clock ratio and gains, shifted.
            f = first;
            const double L0 = -first.tau0() * fs_ / (1 + first.kappa);
            f.tau_c = first.tau_c - (L - L0) * (1 + first.kappa) / fs_;
            std::size_t lo, hi;
            interior(f, lo, hi);
            if (hi <= lo + 32) continue;
            gauss_newton(f, lo, hi, 10);  // starts next to its solution: the ratio and gains are known
            if (!f.ok) continue;
        }
        std::size_t lo, hi;
        interior(f, lo, hi);
        f.ssr = sum_squares(f, lo, hi, 1, &f.srr);
        f.n = hi - lo;
        bool dup = false;
        for (const auto& g : fits) dup |= std::fabs(g.tau0() - f.tau0()) * fs_ < 0.25;
        if (!dup) fits.push_back(f);
    }
    std::vector<double> dec(fits.size());
    std::size_t bi = 0;
    for (std::size_t i = 0; i < fits.size(); ++i) {
        dec[i] = decision_ssr(fits[i]);
        if (dec[i] < dec[bi]) bi = i;
    }
    // The right onset may lie beyond the coarse candidates kept: step from the best by the
    // spacing of the candidates (the signal's apparent period) while that fits better.
    double period_s = 0;
    for (std::size_t i = 0; i < fits.size(); ++i) {
        const double d = std::fabs(fits[i].tau0() - fits[bi].tau0());
        if (i != bi && (period_s == 0 || d < period_s)) period_s = d;
    }
    for (int dir = -1; period_s > 0 && dir <= 1; dir += 2) {
        for (int step = 0; step < 32; ++step) {
            Fit f = fits[bi];
            f.tau_c += dir * period_s;
            std::size_t lo, hi;
            interior(f, lo, hi);
            if (hi <= lo + 32) break;
            gauss_newton(f, lo, hi, 10);
            if (!f.ok) break;
            interior(f, lo, hi);
            f.ssr = sum_squares(f, lo, hi, 1, &f.srr);
            f.n = hi - lo;
            bool dup = false;
            for (const auto& g : fits) dup |= std::fabs(g.tau0() - f.tau0()) * fs_ < 0.25;
            if (dup) break;
            const double d = decision_ssr(f);
            fits.push_back(f);
            dec.push_back(d);
            if (d >= dec[bi]) break;
            bi = fits.size() - 1;
        }
    }
    r.candidates = fits.size();
    const Fit& f = fits[bi];
    r.tau0_s = f.tau0();
    r.clock_offset_ppm = f.kappa * 1e6;
    r.delay_s = -r.tau0_s / (1 + f.kappa);
    r.sin = {f.gs, f.os};
    r.cos = {f.gc, f.oc};
    r.fitted_samples = f.n;
    r.residual_rms_v = std::sqrt(f.ssr / (2.0 * static_cast<double>(std::max<std::size_t>(f.n, 1))));
    r.signal_rms_v = std::sqrt(f.srr / (2.0 * static_cast<double>(std::max<std::size_t>(f.n, 1))));
    r.residual_relative = r.signal_rms_v > 0 ? r.residual_rms_v / r.signal_rms_v : std::numeric_limits<double>::infinity();
    r.delay_std_s = std::sqrt(std::max(0.0, f.var_tau));
    r.clock_offset_std_ppm = std::sqrt(std::max(0.0, f.var_kappa)) * 1e6;
    r.ambiguity_z = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < fits.size(); ++i) {
        if (i == bi) continue;
        const double dssr = std::max(0.0, dec[i] - dec[bi]);
        // The difference of two sums of squares has standard deviation 2 sigma sqrt(dssr).
        const double z = r.residual_rms_v > 0 ? std::sqrt(dssr) / (2 * r.residual_rms_v) : std::numeric_limits<double>::infinity();
        if (z < r.ambiguity_z) {
            r.ambiguity_z = z;
            r.alternative_shift_s = fits[i].tau0() - f.tau0();
        }
    }
    // Confidence (docs/alignment.md "When alignment is refused").
    if (!(r.residual_relative <= o_.max_residual_relative))
        return fail("the fit leaves a residual of " + fmt(r.residual_rms_v) + " V rms, " + fmt(r.residual_relative) + " of the signal (limit " +
                    fmt(o_.max_residual_relative) + "): the recorded signal is not the played one up to delay, clock offset, gain and offset "
                    "(distortion, bandwidth, a wrong channel, or clipping)");
    if (r.sin.gain <= 0 || r.cos.gain <= 0)
        return fail(std::string("the ") + (r.sin.gain <= 0 ? "sin" : "cos") + " channel is inverted or absent (gain " +
                    fmt(r.sin.gain <= 0 ? r.sin.gain : r.cos.gain) + ")");
    if (std::fabs(r.clock_offset_ppm) > o_.max_clock_offset_ppm)
        return fail("the clock offset " + fmt(r.clock_offset_ppm) + " ppm exceeds the plausible " + fmt(o_.max_clock_offset_ppm) + " ppm");
    if (r.delay_std_s * fs_ > o_.max_delay_std_samples)
        return fail("the delay is uncertain by " + fmt(r.delay_std_s * fs_) + " samples (standard error; limit " + fmt(o_.max_delay_std_samples) + ")");
    if (r.ambiguity_z < o_.min_ambiguity_z)
        return fail("ambiguous delay: shifting it by " + fmt(r.alternative_shift_s) + " s fits the record almost as well (" + fmt(r.ambiguity_z) +
                    " standard deviations apart, " + fmt(o_.min_ambiguity_z) + " needed): the signal repeats and the record does not show where the "
                    "output started (the record must start before the output)");
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
         {"channels", {{"sin", {{"gain", num(r.sin.gain)}, {"offset_v", num(r.sin.offset_v)}}}, {"cos", {{"gain", num(r.cos.gain)}, {"offset_v", num(r.cos.offset_v)}}}}},
         {"residual_rms_v", num(r.residual_rms_v)},
         {"signal_rms_v", num(r.signal_rms_v)},
         {"residual_relative", num(r.residual_relative)},
         {"confidence", {{"correlation", num(r.correlation)}, {"correlation_sin", num(r.correlation_sin)}, {"correlation_cos", num(r.correlation_cos)},
                         {"delay_std_s", num(r.delay_std_s)}, {"clock_offset_std_ppm", num(r.clock_offset_std_ppm)},
                         {"ambiguity_z", num(r.ambiguity_z)}, {"alternative_shift_s", r.candidates > 1 ? num(r.alternative_shift_s) : nlohmann::json()},
                         {"candidates", r.candidates}}},
         {"fitted_samples", r.fitted_samples},
         {"method", r.method}};
    j["error"] = r.ok ? nlohmann::json() : nlohmann::json(r.error);
}

}  // namespace fringe
