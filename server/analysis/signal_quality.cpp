#include "server/analysis/signal_quality.hpp"

#include "signal_gen/base/constants.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>

namespace fringe {

using nlohmann::json;

namespace {

double wrap_deg(double d) {
    d = std::fmod(d, 360.0);
    if (d <= -180.0) d += 360.0;
    if (d > 180.0) d -= 360.0;
    return d;
}

// cos and sin of 2 pi g / kGrid: the fitted shape's extremes are sought on this grid; and
// harmonic k's values there, ck[k - 1][j] = c[j k mod kGrid] (sk likewise), so the shape on the
// grid is a pass over j per harmonic that vectorises.
constexpr int kGrid = 128;
struct GridTable {
    double c[kGrid], s[kGrid];
    double ck[SignalQuality::kHarmonics][kGrid], sk[SignalQuality::kHarmonics][kGrid];
    GridTable() {
        for (int g = 0; g < kGrid; ++g) {
            c[g] = std::cos(kTwoPi * g / kGrid);
            s[g] = std::sin(kTwoPi * g / kGrid);
        }
        for (int k = 1; k <= SignalQuality::kHarmonics; ++k)
            for (int j = 0; j < kGrid; ++j) {
                ck[k - 1][j] = c[(j * k) % kGrid];
                sk[k - 1][j] = s[(j * k) % kGrid];
            }
    }
};
const GridTable& grid() {
    static const GridTable t;
    return t;
}

struct Coeffs {
    double c0 = 0, a[SignalQuality::kHarmonics + 1] = {}, b[SignalQuality::kHarmonics + 1] = {};
};

// cos(k phi) and sin(k phi), k = 1..K, of each point by the angle-addition recurrence from its
// cos and sin, once a period for both channels' series and shapes: harmonic k's row at
// (k - 1) * n, each row a pass over the points that vectorises.
void harmonic_table(const std::vector<double>& c1v, const std::vector<double>& s1v, std::vector<double>& ck_tab, std::vector<double>& sk_tab) {
    constexpr int K = SignalQuality::kHarmonics;
    const std::size_t n = c1v.size();
    ck_tab.resize(n * K);
    sk_tab.resize(n * K);
    const double* c1 = c1v.data();
    const double* s1 = s1v.data();
    std::copy(c1, c1 + n, ck_tab.data());
    std::copy(s1, s1 + n, sk_tab.data());
    for (int k = 2; k <= K; ++k) {
        const double* cp = ck_tab.data() + static_cast<std::size_t>(k - 2) * n;
        const double* sp = sk_tab.data() + static_cast<std::size_t>(k - 2) * n;
        double* cr = ck_tab.data() + static_cast<std::size_t>(k - 1) * n;
        double* sr = sk_tab.data() + static_cast<std::size_t>(k - 1) * n;
#pragma omp simd
        for (std::size_t i = 0; i < n; ++i) {
            cr[i] = cp[i] * c1[i] - sp[i] * s1[i];
            sr[i] = sp[i] * c1[i] + cp[i] * s1[i];
        }
    }
}

// Fourier series of both channels over one period, by the trapezoid rule on the period's
// points (many points: the interpolated end points cost nothing), from the harmonic table.
void coeffs_trapezoid(const std::vector<double>& ck_tab, const std::vector<double>& sk_tab, const std::vector<double>& w,
                      const std::vector<double>& xa, const std::vector<double>& xb, Coeffs& fa, Coeffs& fb) {
    constexpr int K = SignalQuality::kHarmonics;
    fa = Coeffs{};
    fb = Coeffs{};
    const std::size_t n = w.size();
    for (std::size_t i = 0; i < n; ++i) {
        const double wa = w[i] * xa[i], wb = w[i] * xb[i];
        fa.c0 += wa;
        fb.c0 += wb;
        for (int k = 1; k <= K; ++k) {
            const double ck = ck_tab[static_cast<std::size_t>(k - 1) * n + i], sk = sk_tab[static_cast<std::size_t>(k - 1) * n + i];
            fa.a[k] += wa * ck;
            fa.b[k] += wa * sk;
            fb.a[k] += wb * ck;
            fb.b[k] += wb * sk;
        }
    }
    for (Coeffs* f : {&fa, &fb}) {
        f->c0 /= kTwoPi;
        for (int k = 1; k <= K; ++k) {
            f->a[k] /= kPi;
            f->b[k] /= kPi;
        }
    }
}

// The same series by least squares on the samples alone (few points a period: the trapezoid
// rule's interpolated end points and its uneven last interval would leak into the harmonics).
void coeffs_least_squares(const std::vector<double>& ck_tab, const std::vector<double>& sk_tab, const std::vector<double>& xa,
                          const std::vector<double>& xb, Coeffs& fa, Coeffs& fb) {
    constexpr int K = SignalQuality::kHarmonics, P = 2 * K + 1;
    Eigen::Matrix<double, P, P> ata = Eigen::Matrix<double, P, P>::Zero();
    Eigen::Matrix<double, P, 2> atb = Eigen::Matrix<double, P, 2>::Zero();
    Eigen::Matrix<double, P, 1> row;
    const std::size_t n = xa.size();
    for (std::size_t i = 1; i + 1 < n; ++i) {  // the samples, not the interpolated ends
        row(0) = 1;
        for (int k = 1; k <= K; ++k) {
            row(2 * k - 1) = ck_tab[static_cast<std::size_t>(k - 1) * n + i];
            row(2 * k) = sk_tab[static_cast<std::size_t>(k - 1) * n + i];
        }
        ata.selfadjointView<Eigen::Lower>().rankUpdate(row);
        atb.col(0) += row * xa[i];
        atb.col(1) += row * xb[i];
    }
    const Eigen::Matrix<double, P, 2> sol = ata.selfadjointView<Eigen::Lower>().ldlt().solve(atb);
    for (int ch = 0; ch < 2; ++ch) {
        Coeffs& f = ch == 0 ? fa : fb;
        f.c0 = sol(0, ch);
        for (int k = 1; k <= K; ++k) {
            f.a[k] = sol(2 * k - 1, ch);
            f.b[k] = sol(2 * k, ch);
        }
    }
}

// A channel's figures from its series and its points.
ChannelQuality channel_figures(const Coeffs& f, const std::vector<double>& phi, const std::vector<double>& ck_tab, const std::vector<double>& sk_tab,
                               const std::vector<double>& x) {
    constexpr int K = SignalQuality::kHarmonics;
    const std::size_t n = phi.size();
    const double c0 = f.c0;
    const double* a = f.a;
    const double* b = f.b;
    ChannelQuality q;
    q.amplitude_v = std::hypot(a[1], b[1]);
    q.vpp_v = 2 * q.amplitude_v;
    q.offset_v = c0;
    q.phase_rad = std::atan2(a[1], b[1]);  // amplitude sin(phi + p) = amplitude (sin phi cos p + cos phi sin p)
    double h2 = 0;
    for (int k = 2; k <= K; ++k) {
        const double hk = q.amplitude_v > 0 ? 100.0 * std::hypot(a[k], b[k]) / q.amplitude_v : 0.0;
        q.h_percent[k - 2] = hk;
        h2 += hk * hk;
    }
    q.thd_percent = std::sqrt(h2);
    // The fitted shape's extremes on a fine grid (the samples' own extremes grow with noise).
    const GridTable& g = grid();
    q.max_v = -std::numeric_limits<double>::infinity();
    q.min_v = std::numeric_limits<double>::infinity();
    double vals[kGrid];
    for (int j = 0; j < kGrid; ++j) vals[j] = c0;
    for (int k = 1; k <= K; ++k) {  // each grid value's terms in the order k = 1..K
        const double ak = a[k], bk = b[k];
        const double* ckj = g.ck[k - 1];
        const double* skj = g.sk[k - 1];
#pragma omp simd
        for (int j = 0; j < kGrid; ++j) vals[j] += ak * ckj[j] + bk * skj[j];
    }
    int jmax = 0, jmin = 0;
    for (int j = 1; j < kGrid; ++j) {
        if (vals[j] > vals[jmax]) jmax = j;
        if (vals[j] < vals[jmin]) jmin = j;
    }
    // The extreme between grid points: the parabola through the best point and its neighbours.
    auto refine = [&](int j) {
        const double y0 = vals[(j + kGrid - 1) % kGrid], y1 = vals[j], y2 = vals[(j + 1) % kGrid], den = y0 - 2 * y1 + y2;
        return den != 0 ? y1 - 0.125 * (y2 - y0) * (y2 - y0) / den : y1;
    };
    q.max_v = refine(jmax);
    q.min_v = refine(jmin);
    const double P = q.max_v, N = -q.min_v, M = q.max_v - q.min_v;
    q.sym = M > 0 ? std::fabs(P - N) / (2 * M) : 0.0;
    // Noise: the samples about the shape (the interpolated end points are not samples). The
    // shape at every point first, harmonic by harmonic (each point's terms in the order k = 1..K).
    thread_local std::vector<double> shape;
    shape.assign(n, c0);
    for (int k = 1; k <= K; ++k) {
        const double ak = a[k], bk = b[k];
        const double* cr = ck_tab.data() + static_cast<std::size_t>(k - 1) * n;
        const double* sr = sk_tab.data() + static_cast<std::size_t>(k - 1) * n;
        double* v = shape.data();
#pragma omp simd
        for (std::size_t i = 0; i < n; ++i) v[i] += ak * cr[i] + bk * sr[i];
    }
    double r2 = 0;
    for (std::size_t i = 1; i + 1 < n; ++i) {
        const double d = x[i] - shape[i];
        r2 += d * d;
    }
    // 2K + 1 coefficients were fitted to these points: the residual has that many fewer degrees of freedom.
    const double dof = static_cast<double>(n) - 2.0 - (2 * K + 1);
    q.noise_v_rms = dof > 0 ? std::sqrt(r2 / dof) : 0.0;
    // On/off ratio: the share of the period the fitted shape is above 0 V (its crossings
    // interpolated between grid points). The samples' own crossings flicker with the noise,
    // and the period's ends sit on one channel's crossings.
    double high = 0;
    for (int j = 0; j < kGrid; ++j) {
        const double x0 = vals[j], x1 = vals[(j + 1) % kGrid];
        if (x0 > 0 && x1 > 0) high += 1;
        else if (x0 > 0 || x1 > 0) {
            const double cross = x0 / (x0 - x1);  // where the segment crosses 0
            high += x0 > 0 ? cross : 1 - cross;
        }
    }
    q.tv_deg = high * 360.0 / kGrid - 180.0;
    return q;
}

}  // namespace

PeriodQuality SignalQuality::analyse_period(const std::vector<double>& t_s, const std::vector<double>& phi, const std::vector<double>& a_v,
                                            const std::vector<double>& b_v) {
    PeriodQuality p;
    // The radius over every sample (as a monitor sees it), the shape from at most kFitPoints:
    // 256 points a period resolve the 8th harmonic and the zero crossings; more only cost.
    p.radius_min_v = std::numeric_limits<double>::infinity();
    p.radius_max_v = 0;
    {
        double r2_min = std::numeric_limits<double>::infinity(), r2_max = 0;
        const std::size_t last = phi.size() > 0 ? phi.size() - 1 : 0;
        const double* av = a_v.data();
        const double* bv = b_v.data();
        // the samples are finite: their minimum and maximum in any order are the same
#pragma omp simd reduction(min : r2_min) reduction(max : r2_max)
        for (std::size_t i = 1; i < last; ++i) {
            const double r2 = av[i] * av[i] + bv[i] * bv[i];
            r2_min = std::min(r2_min, r2);
            r2_max = std::max(r2_max, r2);
        }
        p.radius_min_v = phi.size() > 2 ? std::sqrt(r2_min) : 0.0;
        p.radius_max_v = std::sqrt(r2_max);
        if (r2_min < 1e-250 || r2_max < 1e-250) {  // the squares underflow: hypot, sample by sample
            double rmin = std::numeric_limits<double>::infinity(), rmax = 0;
            for (std::size_t i = 1; i + 1 < phi.size(); ++i) {
                const double r = std::hypot(a_v[i], b_v[i]);
                rmin = std::min(rmin, r);
                rmax = std::max(rmax, r);
            }
            p.radius_min_v = phi.size() > 2 ? rmin : 0.0;
            p.radius_max_v = rmax;
        }
    }
    constexpr std::size_t kFitPoints = 256;
    if (phi.size() > kFitPoints + 2) {
        const std::size_t stride = (phi.size() - 2 + kFitPoints - 1) / kFitPoints;
        // scratch kept per thread (this call's own: the call below does not decimate again)
        thread_local std::vector<double> dt, dp, da, db;
        for (auto* v : {&dt, &dp, &da, &db}) v->clear();
        for (std::size_t i = 0; i + 1 < phi.size(); i += (i == 0 ? 1 : stride)) {
            dt.push_back(t_s[i]);
            dp.push_back(phi[i]);
            da.push_back(a_v[i]);
            db.push_back(b_v[i]);
        }
        dt.push_back(t_s.back());
        dp.push_back(phi.back());
        da.push_back(a_v.back());
        db.push_back(b_v.back());
        PeriodQuality q = analyse_period(dt, dp, da, db);
        q.samples = phi.size() - 2;
        q.radius_min_v = p.radius_min_v;
        q.radius_max_v = p.radius_max_v;
        return q;
    }
    const std::size_t n = phi.size();
    thread_local std::vector<double> w, c1, s1, ck_tab, sk_tab;  // scratch kept per thread
    w.assign(n, 0.0);
    for (std::size_t i = 0; i + 1 < n; ++i) {
        const double h = 0.5 * std::fabs(phi[i + 1] - phi[i]);
        w[i] += h;
        w[i + 1] += h;
    }
    p.t_start_s = t_s.front();
    p.t_end_s = t_s.back();
    p.direction = phi.back() >= phi.front() ? 1 : -1;
    p.samples = n >= 2 ? n - 2 : 0;
    // cos and sin of each angle: exact at the ends, at point 1 and every 64 points, rotated in
    // between. Sampling is uniform inside a period (its ends are the interpolated crossings):
    // when every step from point 1 to point n-2 is within 1e-9 of the first (time stamps far
    // into a run differ by 1e-10 relative), point e + j is point e (exact) turned by j steps,
    // from a table of cos, sin of j steps (one chain of 63 rotations a period, then a pass that
    // vectorises; at most 2e-9 rad off). Otherwise one rotation per step, in order.
    c1.resize(n);
    s1.resize(n);
    constexpr std::size_t kExact = 64;
    bool uniform = n > 4;
    const double step1 = n > 2 ? phi[2] - phi[1] : 0.0;
    if (uniform) {
        const double* ph = phi.data();
        std::size_t off = 0;
#pragma omp simd reduction(+ : off)
        for (std::size_t i = 2; i < n - 1; ++i) off += !(std::fabs((ph[i] - ph[i - 1]) - step1) <= 1e-9 * std::fabs(step1));
        uniform = off == 0;
    }
    if (uniform) {
        double tc[kExact], ts[kExact];  // cos, sin of j steps
        tc[0] = 1;
        ts[0] = 0;
        tc[1] = std::cos(step1);
        ts[1] = std::sin(step1);
        for (std::size_t j = 2; j < kExact; ++j) {
            tc[j] = tc[j - 1] * tc[1] - ts[j - 1] * ts[1];
            ts[j] = ts[j - 1] * tc[1] + tc[j - 1] * ts[1];
        }
        c1[0] = std::cos(phi[0]);
        s1[0] = std::sin(phi[0]);
        for (std::size_t e = 1; e + 1 < n; e += kExact) {  // blocks from points 1, 65, 129, ...
            const double ce = std::cos(phi[e]), se = std::sin(phi[e]);
            const std::size_t len = std::min(kExact, n - 1 - e);
            double* cc = c1.data() + e;
            double* ss = s1.data() + e;
#pragma omp simd
            for (std::size_t j = 0; j < len; ++j) {
                cc[j] = ce * tc[j] - se * ts[j];
                ss[j] = se * tc[j] + ce * ts[j];
            }
            cc[0] = ce;
            ss[0] = se;
        }
        c1[n - 1] = std::cos(phi[n - 1]);
        s1[n - 1] = std::sin(phi[n - 1]);
    } else {
        double last_step = std::numeric_limits<double>::quiet_NaN(), rc = 1, rs = 0;
        for (std::size_t i = 0; i < n; ++i) {
            if (i == 0 || i + 1 == n || i % kExact == 0) {
                c1[i] = std::cos(phi[i]);
                s1[i] = std::sin(phi[i]);
                continue;
            }
            const double step = phi[i] - phi[i - 1];
            if (!(std::fabs(step - last_step) <= 1e-9 * std::fabs(step))) {
                rc = std::cos(step);
                rs = std::sin(step);
                last_step = step;
            }
            c1[i] = c1[i - 1] * rc - s1[i - 1] * rs;
            s1[i] = s1[i - 1] * rc + c1[i - 1] * rs;
        }
    }
    harmonic_table(c1, s1, ck_tab, sk_tab);
    Coeffs fa, fb;
    if (n < kLeastSquaresBelow) coeffs_least_squares(ck_tab, sk_tab, a_v, b_v, fa, fb);
    else coeffs_trapezoid(ck_tab, sk_tab, w, a_v, b_v, fa, fb);
    p.a = channel_figures(fa, phi, ck_tab, sk_tab, a_v);
    p.b = channel_figures(fb, phi, ck_tab, sk_tab, b_v);
    p.ab_ratio = p.b.amplitude_v > 0 ? p.a.amplitude_v / p.b.amplitude_v : 0.0;
    p.phase_deg = wrap_deg((p.b.phase_rad - p.a.phase_rad) * 180.0 / kPi);
    p.freq_hz = p.t_end_s > p.t_start_s ? 1.0 / (p.t_end_s - p.t_start_s) : 0.0;
    return p;
}

void SignalQuality::start_period(double t, double a, double b, long long k, int direction) {
    open_ = true;
    too_long_ = false;
    k_start_ = k;
    dir_ = direction;
    pt_.assign(1, t);
    pa_.assign(1, a);
    pb_.assign(1, b);
}

void SignalQuality::close_period(double t, double a, double b) {
    open_ = false;
    if (too_long_) {
        ++skipped_;
        ++skipped_long_;
        return;
    }
    pt_.push_back(t);
    pa_.push_back(a);
    pb_.push_back(b);
    const double t0 = pt_.front(), T = t - t0;
    // The period before, if this one follows it directly in the same direction: its length
    // tells whether the speed held (the angle is taken as linear in time within a period).
    const double prev_T = prev_period_end_ == t0 && prev_period_dir_ == dir_ ? prev_period_T_ : 0.0;
    prev_period_end_ = t;
    prev_period_dir_ = dir_;
    prev_period_T_ = T;
    if (!(T > 0) || pt_.size() < kMinPeriodSamples + 2) {  // too few samples to fit 17 coefficients and keep some noise
        ++skipped_;
        ++skipped_short_;
        return;
    }
    if (!(prev_T > 0)) {  // the first period after a start, a gap or a turn: the speed before it is unknown
        ++skipped_;
        ++skipped_unsteady_;
        return;
    }
    if (std::fabs(T / prev_T - 1.0) > kMaxPeriodChange) {
        ++skipped_;
        ++skipped_unsteady_;
        return;
    }
    std::vector<double>& phi = phi_;
    phi.resize(pt_.size());
    {
        const double* pt = pt_.data();
        double* ph = phi.data();
        const double d2pi = dir_ * kTwoPi;
#pragma omp simd
        for (std::size_t i = 0; i < phi.size(); ++i) ph[i] = d2pi * (pt[i] - t0) / T;
    }
    const PeriodQuality p = analyse_period(pt_, phi, pa_, pb_);
    const bool finite = std::isfinite(p.a.amplitude_v) && std::isfinite(p.b.amplitude_v) && std::isfinite(p.a.noise_v_rms) &&
                        std::isfinite(p.b.noise_v_rms) && std::isfinite(p.phase_deg) && std::isfinite(p.ab_ratio) && p.b.amplitude_v > 0;
    if (!finite) {
        ++skipped_;
        return;
    }
    bin_lissajous(phi);
    if (!have_worst_) {
        worst_lo_ = worst_hi_ = p;
        radius_min_v_ = p.radius_min_v;
        radius_max_v_ = p.radius_max_v;
        have_worst_ = true;
    }
    auto lohi = [](double v, double& lo, double& hi) {
        lo = std::min(lo, v);
        hi = std::max(hi, v);
    };
    lohi(p.a.vpp_v, worst_lo_.a.vpp_v, worst_hi_.a.vpp_v);
    lohi(p.b.vpp_v, worst_lo_.b.vpp_v, worst_hi_.b.vpp_v);
    lohi(p.ab_ratio, worst_lo_.ab_ratio, worst_hi_.ab_ratio);
    lohi(p.phase_deg, worst_lo_.phase_deg, worst_hi_.phase_deg);
    lohi(p.a.tv_deg, worst_lo_.a.tv_deg, worst_hi_.a.tv_deg);
    lohi(p.b.tv_deg, worst_lo_.b.tv_deg, worst_hi_.b.tv_deg);
    radius_min_v_ = std::min(radius_min_v_, p.radius_min_v);
    radius_max_v_ = std::max(radius_max_v_, p.radius_max_v);
    // Running sums for the means.
    auto add_ch = [](ChannelQuality& s, const ChannelQuality& c) {
        s.amplitude_v += c.amplitude_v;
        s.vpp_v += c.vpp_v;
        s.offset_v += c.offset_v;
        s.tv_deg += c.tv_deg;
        s.sym += c.sym;
        for (std::size_t k = 0; k < s.h_percent.size(); ++k) s.h_percent[k] += c.h_percent[k];
        s.thd_percent += c.thd_percent;
        s.noise_v_rms += c.noise_v_rms * c.noise_v_rms;  // mean square
        s.max_v += c.max_v;
        s.min_v += c.min_v;
    };
    add_ch(sum_.a, p.a);
    add_ch(sum_.b, p.b);
    sum_.ab_ratio += p.ab_ratio;
    sum_.phase_deg += p.phase_deg;
    sum_.freq_hz += p.freq_hz;
    sum_.samples += p.samples;
    ++periods_;
    auto mean_ch = [&](const ChannelQuality& s) {
        ChannelQuality m = s;
        const double n = static_cast<double>(periods_);
        m.amplitude_v /= n;
        m.vpp_v /= n;
        m.offset_v /= n;
        m.tv_deg /= n;
        m.sym /= n;
        for (auto& h : m.h_percent) h /= n;
        m.thd_percent /= n;
        m.noise_v_rms = std::sqrt(m.noise_v_rms / n);
        m.max_v /= n;
        m.min_v /= n;
        return m;
    };
    mean_.a = mean_ch(sum_.a);
    mean_.b = mean_ch(sum_.b);
    mean_.ab_ratio = sum_.ab_ratio / static_cast<double>(periods_);
    mean_.phase_deg = sum_.phase_deg / static_cast<double>(periods_);
    mean_.freq_hz = sum_.freq_hz / static_cast<double>(periods_);
    record(p, dir_ > 0 ? k_start_ : k_start_ - 1);
}

void SignalQuality::bin_lissajous(const std::vector<double>& phi_rad) {
    const double scale = static_cast<double>(kLissajousBins) / kTwoPi;
    const std::size_t n = phi_rad.size();
    // Each sample's bin first (a pass that vectorises); then the sums, a bin's kept in registers
    // while its samples last (neighbours share a bin: a period's ~kLissajousBins runs), added in
    // sample order.
    bins_.resize(n);
    std::uint32_t* kb = bins_.data();
    const double* ph = phi_rad.data();
#pragma omp simd
    for (std::size_t i = 0; i < n; ++i) {
        double u = ph[i] * scale;  // backwards, phi runs 0..-2 pi: its angle is 2 pi + phi
        u = u < 0 ? u + static_cast<double>(kLissajousBins) : u;
        const double k = u < static_cast<double>(kLissajousBins - 1) ? std::trunc(u) : static_cast<double>(kLissajousBins - 1);
        kb[i] = static_cast<std::uint32_t>(k);
    }
    const double* pa = pa_.data();
    const double* pb = pb_.data();
    for (std::size_t i = 1; i + 1 < n;) {  // the first and last points are the crossings, not samples
        const std::uint32_t k = kb[i];
        LissajousBin& bin = lissajous_[k];
        double sa = bin.sum_a_v, sb = bin.sum_b_v, lo = bin.r2_min, hi = bin.r2_max;
        std::size_t c = bin.count;
        do {
            const double a = pa[i], b = pb[i], r2 = a * a + b * b;
            sa += a;
            sb += b;
            lo = std::min(lo, r2);
            hi = std::max(hi, r2);
            ++c;
            ++i;
        } while (i + 1 < n && kb[i] == k);
        bin.sum_a_v = sa;
        bin.sum_b_v = sb;
        bin.r2_min = lo;
        bin.r2_max = hi;
        bin.count = c;
    }
}

void SignalQuality::record(const PeriodQuality& p, long long position) {
    const double n = static_cast<double>(pending_.count), m = n + 1;
    auto blend = [&](double& acc, double v) { acc = (acc * n + v) / m; };
    if (pending_.count == 0) {
        pending_.first = periods_ - 1;
        pending_.position = position;
    }
    blend(pending_.t_s, 0.5 * (p.t_start_s + p.t_end_s));
    blend(pending_.vpp_a, p.a.vpp_v);
    blend(pending_.vpp_b, p.b.vpp_v);
    blend(pending_.ratio, p.ab_ratio);
    blend(pending_.phase_deg, p.phase_deg);
    blend(pending_.tv_a, p.a.tv_deg);
    blend(pending_.tv_b, p.b.tv_deg);
    blend(pending_.offset_a, p.a.offset_v);
    blend(pending_.offset_b, p.b.offset_v);
    ++pending_.count;
    if (pending_.count < per_record_) return;
    records_.push_back(pending_);
    pending_ = Record{};
    if (records_.size() < kMaxRecords) return;
    // Full: every two neighbours become one, and each bucket takes twice as many periods.
    std::vector<Record> merged;
    merged.reserve(kMaxRecords / 2);
    for (std::size_t i = 0; i + 1 < records_.size(); i += 2) {
        const Record& x = records_[i];
        const Record& y = records_[i + 1];
        const double wx = static_cast<double>(x.count), wy = static_cast<double>(y.count), s = wx + wy;
        auto mix = [&](double u, double v) { return (u * wx + v * wy) / s; };
        merged.push_back({x.first, x.count + y.count, x.position, mix(x.t_s, y.t_s), mix(x.vpp_a, y.vpp_a), mix(x.vpp_b, y.vpp_b), mix(x.ratio, y.ratio),
                          mix(x.phase_deg, y.phase_deg), mix(x.tv_a, y.tv_a), mix(x.tv_b, y.tv_b), mix(x.offset_a, y.offset_a), mix(x.offset_b, y.offset_b)});
    }
    records_ = std::move(merged);
    per_record_ *= 2;
}

namespace {
// The quadrant of psi = atan2(A, B): 0 for [0, pi/2), 1 for [pi/2, pi), 2 for [pi, 3pi/2),
// 3 for [3pi/2, 2pi); -1 at the origin. psi crosses a multiple of 2 pi going from 3 to 0 (A
// rising through 0 while B > 0) or back.
int quadrant(double a, double b) {
    if (a >= 0 && b > 0) return 0;
    if (a > 0 && b <= 0) return 1;
    if (a <= 0 && b < 0) return 2;
    if (a < 0 && b >= 0) return 3;
    return -1;
}
}  // namespace

namespace {
// The first index from i on (n if none) whose sample is not usable or not in quadrant Q,
// kScan samples at a time while all are (a pass that vectorises), then one at a time.
template <int Q>
std::size_t scan_run_q(const double* t_s, const double* a_v, const double* b_v, std::size_t i, std::size_t n) {
    constexpr std::size_t kScan = 32;
    constexpr double kMax = SignalQuality::kMaxAbsV;
    std::size_t j = i;
    while (j + kScan <= n) {
        unsigned bad = 0;
#pragma omp simd reduction(+ : bad)
        for (std::size_t k = 0; k < kScan; ++k) {
            const double t = t_s[j + k], a = a_v[j + k], b = b_v[j + k];
            // quadrant(a, b) == Q as two comparisons (false for NaN, as quadrant() gives -2 then)
            const bool in_q = Q == 0 ? (a >= 0) & (b > 0) : Q == 1 ? (a > 0) & (b <= 0) : Q == 2 ? (a <= 0) & (b < 0) : (a < 0) & (b >= 0);
            bad += static_cast<unsigned>(!(((t - t) == 0.0) & (std::fabs(a) < kMax) & (std::fabs(b) < kMax) & in_q));
        }
        if (bad) break;
        j += kScan;
    }
    while (j < n && std::isfinite(t_s[j]) && std::fabs(a_v[j]) < kMax && std::fabs(b_v[j]) < kMax && quadrant(a_v[j], b_v[j]) == Q) ++j;
    return j;
}
std::size_t scan_run(const double* t_s, const double* a_v, const double* b_v, std::size_t i, std::size_t n, int q) {
    switch (q) {
    case 0: return scan_run_q<0>(t_s, a_v, b_v, i, n);
    case 1: return scan_run_q<1>(t_s, a_v, b_v, i, n);
    case 2: return scan_run_q<2>(t_s, a_v, b_v, i, n);
    case 3: return scan_run_q<3>(t_s, a_v, b_v, i, n);
    default: return i;
    }
}
}  // namespace

void SignalQuality::add(const double* t_s, const double* a_v, const double* b_v, std::size_t n) {
    for (std::size_t i = 0; i < n; ++i) {
        // Most samples are usable and in the quadrant of the one before: such a run is counted
        // and kept in bulk (what the sample-by-sample path below does with each of them).
        if (have_prev_) {
            std::size_t j = scan_run(t_s, a_v, b_v, i, n, prev_q_);
            if (j > i) {
                samples_ += j - i;
                if (open_ && !too_long_) {
                    if (pt_.size() + (j - i) <= kMaxPeriodSamples) {
                        pt_.insert(pt_.end(), t_s + i, t_s + j);
                        pa_.insert(pa_.end(), a_v + i, a_v + j);
                        pb_.insert(pb_.end(), b_v + i, b_v + j);
                    } else {  // the sample that finds the period full marks it too long
                        too_long_ = true;
                        pt_.clear();
                        pa_.clear();
                        pb_.clear();
                    }
                }
                prev_t_ = t_s[j - 1];
                prev_a_ = a_v[j - 1];
                prev_b_ = b_v[j - 1];
                i = j;
                if (i == n) break;
            }
        }
        const double t = t_s[i], a = a_v[i], b = b_v[i];
        // A sample beyond 1e100 V would overflow the squares of the fit: a gap, like a non-finite one.
        const bool usable = std::isfinite(t) && std::fabs(a) < kMaxAbsV && std::fabs(b) < kMaxAbsV;
        const int q = usable ? quadrant(a, b) : -2;
        if (q == -2) {  // a gap: the open period is lost
            if (open_) ++skipped_;
            if (std::isfinite(a) && std::isfinite(b) && std::isfinite(t)) ++out_of_range_;
            open_ = false;
            have_prev_ = false;
            prev_period_end_ = std::numeric_limits<double>::quiet_NaN();
            continue;
        }
        ++samples_;
        if (q < 0) continue;  // exactly at the origin: no angle
        if (!have_prev_) {
            prev_t_ = t;
            prev_a_ = a;
            prev_b_ = b;
            prev_q_ = q;
            quarter_ = q;
            have_prev_ = true;
            continue;
        }
        const int d = (q - prev_q_ + 4) % 4;
        if (d == 2) {  // half a turn between two samples: the direction is unknown
            if (open_) ++skipped_;
            open_ = false;
            prev_period_end_ = std::numeric_limits<double>::quiet_NaN();
        } else if (d != 0) {
            const int s = d == 1 ? 1 : -1;
            const long long k0 = floor_div4(quarter_);
            quarter_ += s;
            const long long k1 = floor_div4(quarter_);
            // A turn: the angle went back half a quadrant past the open period's start (noise
            // that only flickers across the start boundary is not a turn).
            if (open_ && ((dir_ > 0 && quarter_ <= 4 * k_start_ - 2) || (dir_ < 0 && quarter_ >= 4 * k_start_ + 1))) {
                ++skipped_;
                ++skipped_unsteady_;
                open_ = false;
                prev_period_end_ = std::numeric_limits<double>::quiet_NaN();
            }
            if (k1 != k0) {
                const long long m = s > 0 ? k1 : k0;  // the boundary 2 pi m crossed: A through 0 with B > 0
                const double f = prev_a_ / (prev_a_ - a);
                const double tc = prev_t_ + f * (t - prev_t_), bc = prev_b_ + f * (b - prev_b_);
                if (open_ && dir_ == s && k_start_ + s == m) {
                    close_period(tc, 0.0, bc);  // the first crossing of the end, as of the start
                    start_period(tc, 0.0, bc, m, s);
                } else if (open_ && m == k_start_) {
                    // noise flickering across the start boundary: the period keeps its first crossing
                } else {
                    if (open_) ++skipped_;
                    start_period(tc, 0.0, bc, m, s);
                }
            }
        }
        if (open_ && !too_long_) {
            if (pt_.size() >= kMaxPeriodSamples) {
                too_long_ = true;
                pt_.clear();
                pa_.clear();
                pb_.clear();
            } else {
                pt_.push_back(t);
                pa_.push_back(a);
                pb_.push_back(b);
            }
        }
        prev_t_ = t;
        prev_a_ = a;
        prev_b_ = b;
        prev_q_ = q;
    }
}

json SignalQuality::to_json() const {
    if (periods_ == 0) {
        std::string note = "no whole electrical period in the signals (the angle atan2(A, B) never went once round between two multiples of 2 pi)";
        if (out_of_range_ > 0)
            note = std::to_string(out_of_range_) + " samples beyond 1e100 V: no figure of such signals is computed";
        else if (samples_ == 0)
            note = "no samples";
        else if (skipped_short_ > 0)
            note = std::to_string(skipped_short_) + " period" + (skipped_short_ == 1 ? "" : "s") + " with fewer than " + std::to_string(kMinPeriodSamples) +
                   " samples each: too few samples per electrical cycle to fit the 8th harmonic and see the noise";
        else if (skipped_long_ > 0)
            note = std::to_string(skipped_long_) + " period" + (skipped_long_ == 1 ? "" : "s") + " longer than " + std::to_string(kMaxPeriodSamples) +
                   " samples each (slower than the analysis takes)";
        else if (skipped_unsteady_ > 0)
            note = std::to_string(skipped_unsteady_) + " period" + (skipped_unsteady_ == 1 ? "" : "s") +
                   " where the speed changed by more than 5 % from the period before, or next to a turn (the analysis needs two whole periods at a steady speed)";
        return {{"periods", 0}, {"skipped_periods", skipped_}, {"samples", samples_}, {"note", note}};
    }
    auto ch = [&](const ChannelQuality& c, const ChannelQuality& lo, const ChannelQuality& hi) {
        json h = json::object();
        static const char* const kNames[] = {"h2", "h3", "h4", "h5", "h6", "h7", "h8"};
        for (std::size_t k = 0; k < c.h_percent.size(); ++k) h[kNames[k]] = c.h_percent[k];
        return json{{"amplitude_v", c.amplitude_v}, {"vpp_v", c.vpp_v}, {"offset_v", c.offset_v},
                    {"offset_percent", c.amplitude_v > 0 ? 100.0 * c.offset_v / c.amplitude_v : 0.0}, {"tv_deg", c.tv_deg}, {"sym", c.sym},
                    {"harmonics_percent", h}, {"thd_percent", c.thd_percent}, {"noise_v_rms", c.noise_v_rms}, {"max_v", c.max_v}, {"min_v", c.min_v},
                    {"vpp_range_v", {lo.vpp_v, hi.vpp_v}}, {"tv_range_deg", {lo.tv_deg, hi.tv_deg}}};
    };
    json rec{{"periods_per_point", per_record_}, {"first_period", json::array()}, {"position_periods", json::array()}, {"t_s", json::array()}, {"vpp_a_v", json::array()},
             {"vpp_b_v", json::array()}, {"ab_ratio", json::array()}, {"phase_deg", json::array()}, {"tv_a_deg", json::array()},
             {"tv_b_deg", json::array()}, {"offset_a_v", json::array()}, {"offset_b_v", json::array()}};
    auto push = [&](const Record& r) {
        rec["first_period"].push_back(r.first);
        rec["position_periods"].push_back(r.position);
        rec["t_s"].push_back(r.t_s);
        rec["vpp_a_v"].push_back(r.vpp_a);
        rec["vpp_b_v"].push_back(r.vpp_b);
        rec["ab_ratio"].push_back(r.ratio);
        rec["phase_deg"].push_back(r.phase_deg);
        rec["tv_a_deg"].push_back(r.tv_a);
        rec["tv_b_deg"].push_back(r.tv_b);
        rec["offset_a_v"].push_back(r.offset_a);
        rec["offset_b_v"].push_back(r.offset_b);
    };
    for (const auto& r : records_) push(r);
    if (pending_.count > 0) push(pending_);
    json liss{{"bins", kLissajousBins}, {"a_v", json::array()}, {"b_v", json::array()}, {"r_min_v", json::array()}, {"r_max_v", json::array()},
              {"samples", json::array()}};
    for (const auto& bin : lissajous_) {
        const bool any = bin.count > 0;
        const double n = static_cast<double>(bin.count);
        liss["a_v"].push_back(any ? json(bin.sum_a_v / n) : json());
        liss["b_v"].push_back(any ? json(bin.sum_b_v / n) : json());
        liss["r_min_v"].push_back(any ? json(std::sqrt(bin.r2_min)) : json());
        liss["r_max_v"].push_back(any ? json(std::sqrt(bin.r2_max)) : json());
        liss["samples"].push_back(bin.count);
    }
    return {{"periods", periods_},
            {"skipped_periods", skipped_},
            {"skipped_unsteady_periods", skipped_unsteady_},
            {"samples", samples_},
            {"freq_hz", mean_.freq_hz},
            {"a", ch(mean_.a, worst_lo_.a, worst_hi_.a)},
            {"b", ch(mean_.b, worst_lo_.b, worst_hi_.b)},
            {"ab_ratio", mean_.ab_ratio},
            {"ab_ratio_range", {worst_lo_.ab_ratio, worst_hi_.ab_ratio}},
            {"phase_deg", mean_.phase_deg},
            {"phase_error_deg", mean_.phase_deg - 90.0},
            {"phase_range_deg", {worst_lo_.phase_deg, worst_hi_.phase_deg}},
            {"radius_min_v", radius_min_v_},
            {"radius_max_v", radius_max_v_},
            {"recording", rec},
            {"lissajous", liss},
            {"method", "each electrical period between crossings of atan2(A, B) through a multiple of 2 pi; angle linear in time within a "
                       "period; Fourier series to the 8th harmonic by the trapezoid rule; figures are means over the periods"}};
}

}  // namespace fringe
