#include "server/analysis/spectrum.hpp"

#include "signal_gen/base/constants.hpp"

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>

namespace fringe {

using nlohmann::json;

namespace {

// Plot values to `digits` significant digits: the JSON halves in size, far beyond what a plot resolves.
double sig(double v, int digits = 6) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.*g", digits, v);
    return std::strtod(buf, nullptr);
}

std::size_t pow2_floor(std::uint64_t x) {
    std::size_t p = 1;
    while (p * 2 <= x) p *= 2;
    return p;
}
std::size_t pow2_ceil(double x) {
    std::size_t p = 1;
    while (static_cast<double>(p) < x && p < (std::size_t{1} << 40)) p *= 2;
    return p;
}
}  // namespace

namespace {
constexpr std::size_t kPad = 24;  // doubles between the scratch arrays: no 4 KiB aliasing between their streams
}

RealPowerSpectrum::RealPowerSpectrum(std::size_t n) : n_(n), m_(n / 2) {
    if (n < 4 || (n & (n - 1)) != 0) throw std::invalid_argument("RealPowerSpectrum: n must be a power of two >= 4");
    for (std::size_t len = m_; len >= 4; len /= 4) {
        const std::size_t n1 = len / 4;
        std::vector<double> t(6 * n1);
        for (std::size_t p = 0; p < n1; ++p)
            for (std::size_t k = 1; k <= 3; ++k) {
                const double a_rad = -kTwoPi * static_cast<double>(k * p) / static_cast<double>(len);
                t[(2 * k - 2) * n1 + p] = std::cos(a_rad);
                t[(2 * k - 1) * n1 + p] = std::sin(a_rad);
            }
        tw_.push_back(std::move(t));
    }
    split_re_.resize(m_ + 1);
    split_im_.resize(m_ + 1);
    for (std::size_t k = 0; k <= m_; ++k) {
        const double a_rad = -kTwoPi * static_cast<double>(k) / static_cast<double>(n_);
        split_re_[k] = std::cos(a_rad);
        split_im_[k] = std::sin(a_rad);
    }
    buf_.assign(4 * (m_ + kPad), 0.0);
}

void RealPowerSpectrum::accumulate(const double* x, double* power) {
    const std::size_t m = m_;
    double* zr = buf_.data();
    double* zi = zr + m + kPad;
    double* yr = zi + m + kPad;
    double* yi = yr + m + kPad;
    // z_k = x_2k + i x_2k+1
#pragma omp simd
    for (std::size_t k = 0; k < m; ++k) {
        zr[k] = x[2 * k];
        zi[k] = x[2 * k + 1];
    }
    // Stockham's decimation in frequency, from one buffer into the other. A radix-4 stage of
    // sub-length len at stride s, for p < len/4 and q < s, with a..d = z[q + s (p + j len/4)]:
    // y[q + s 4p] = (a + c) + (b + d), y[q + s (4p + 1)] = w^p ((a - c) - i (b - d)),
    // y[q + s (4p + 2)] = w^2p ((a + c) - (b + d)), y[q + s (4p + 3)] = w^3p ((a - c) + i (b - d)).
    std::size_t s = 1, len = m;
    for (std::size_t stage = 0; len >= 4; len /= 4, s *= 4, ++stage) {
        const std::size_t n1 = len / 4;
        const double* t = tw_[stage].data();
        auto butterfly = [&](std::size_t q, std::size_t p) __attribute__((always_inline)) {
            const std::size_t i0 = q + s * p, i1 = i0 + s * n1, i2 = i1 + s * n1, i3 = i2 + s * n1;
            const double apc_re = zr[i0] + zr[i2], apc_im = zi[i0] + zi[i2], amc_re = zr[i0] - zr[i2], amc_im = zi[i0] - zi[i2];
            const double bpd_re = zr[i1] + zr[i3], bpd_im = zi[i1] + zi[i3];
            const double jbmd_re = -(zi[i1] - zi[i3]), jbmd_im = zr[i1] - zr[i3];  // i (b - d)
            const double w1r = t[p], w1i = t[n1 + p], w2r = t[2 * n1 + p], w2i = t[3 * n1 + p], w3r = t[4 * n1 + p], w3i = t[5 * n1 + p];
            const std::size_t o = q + s * 4 * p;
            yr[o] = apc_re + bpd_re;
            yi[o] = apc_im + bpd_im;
            double ur = amc_re - jbmd_re, ui = amc_im - jbmd_im;
            yr[o + s] = w1r * ur - w1i * ui;
            yi[o + s] = w1r * ui + w1i * ur;
            ur = apc_re - bpd_re;
            ui = apc_im - bpd_im;
            yr[o + 2 * s] = w2r * ur - w2i * ui;
            yi[o + 2 * s] = w2r * ui + w2i * ur;
            ur = amc_re + jbmd_re;
            ui = amc_im + jbmd_im;
            yr[o + 3 * s] = w3r * ur - w3i * ui;
            yi[o + 3 * s] = w3r * ui + w3i * ur;
        };
        if (s >= 8) {  // along q: contiguous
            for (std::size_t p = 0; p < n1; ++p) {
#pragma omp simd
                for (std::size_t q = 0; q < s; ++q) butterfly(q, p);
            }
        } else {  // along p
            for (std::size_t q = 0; q < s; ++q) {
#pragma omp simd
                for (std::size_t p = 0; p < n1; ++p) butterfly(q, p);
            }
        }
        std::swap(zr, yr);
        std::swap(zi, yi);
    }
    if (len == 2) {  // m not a power of 4: one radix-2 stage
#pragma omp simd
        for (std::size_t q = 0; q < s; ++q) {
            const double ar = zr[q], ai = zi[q], br = zr[q + s], bi = zi[q + s];
            yr[q] = ar + br;
            yi[q] = ai + bi;
            yr[q + s] = ar - br;
            yi[q + s] = ai - bi;
        }
        std::swap(zr, yr);
        std::swap(zi, yi);
    }
    // The split: E_k = (Z_k + conj Z_{m-k}) / 2, O_k = (Z_k - conj Z_{m-k}) / 2i, X_k = E_k + e^{-2 pi i k / n} O_k.
    power[0] += (zr[0] + zi[0]) * (zr[0] + zi[0]);
    power[m] += (zr[0] - zi[0]) * (zr[0] - zi[0]);
    const double* cr = split_re_.data();
    const double* ci = split_im_.data();
#pragma omp simd
    for (std::size_t k = 1; k < m; ++k) {
        const double pr = zr[k], pi = zi[k], qr = zr[m - k], qi = -zi[m - k];  // Z_k and conj Z_{m-k}
        const double er = 0.5 * (pr + qr), ei = 0.5 * (pi + qi);
        const double or_ = 0.5 * (pi - qi), oi = -0.5 * (pr - qr);
        const double xr = er + cr[k] * or_ - ci[k] * oi, xi = ei + cr[k] * oi + ci[k] * or_;
        power[k] += xr * xr + xi * xi;
    }
}

ErrorSpectrum::ErrorSpectrum(double sample_rate_hz, std::size_t segment_samples)
    : fs_(sample_rate_hz), n_(pow2_floor(std::max(segment_samples, kMinSegment))), fft_(n_) {
    window_.resize(n_);
    for (std::size_t i = 0; i < n_; ++i) {
        window_[i] = 0.5 - 0.5 * std::cos(2 * kPi * static_cast<double>(i) / static_cast<double>(n_));  // periodic Hann
        s1_ += window_[i];
        s2_ += window_[i] * window_[i];
    }
    buf_.assign(n_, 0.0);
    power_.assign(n_ / 2 + 1, 0.0);
}

std::size_t ErrorSpectrum::choose_segment(double sample_rate_hz, double electrical_hz, std::uint64_t scored_samples) {
    // At least 4096 samples either way: a fast encoder's harmonics are far apart, but a tracker's
    // error lives below its loop bandwidth, which a short segment cannot resolve.
    std::size_t want = 4096;
    if (electrical_hz > 0 && sample_rate_hz > 0) want = std::max(want, pow2_ceil(8.0 * sample_rate_hz / electrical_hz));
    want = std::clamp(want, kMinSegment, kMaxSegment);
    const std::size_t fit = std::max(pow2_floor(scored_samples / 4), kMinSegment);
    return std::min(want, fit);
}

void ErrorSpectrum::add(std::size_t n, const double* e_rad, const std::uint8_t* ok) {
    const std::size_t mask = n_ - 1;
    constexpr std::size_t kScan = 64;
    for (std::size_t i = 0; i < n;) {
        // The run of usable samples from i (kScan at a time while all are usable, in a pass that
        // vectorises), appended in pieces that complete segments.
        std::size_t j = i;
        while (j + kScan <= n) {
            std::size_t bad = 0;
#pragma omp simd reduction(+ : bad)
            for (std::size_t q = 0; q < kScan; ++q) {
                const double e = e_rad[j + q];
                bad += static_cast<std::size_t>(!((e - e) == 0.0) || (ok && !ok[j + q]));  // e - e: NaN unless finite
            }
            if (bad) break;
            j += kScan;
        }
        while (j < n && (!ok || ok[j]) && std::isfinite(e_rad[j])) ++j;
        for (std::size_t k = i; k < j;) {
            const std::size_t take = std::min(j - k, n_ - fill_);
            // into the ring from (start_ + fill_) mod n_: up to its end, then from its start
            const std::size_t at = (start_ + fill_) & mask, first = std::min(take, n_ - at);
            std::copy_n(e_rad + k, first, buf_.data() + at);
            std::copy_n(e_rad + k + first, take - first, buf_.data());
            fill_ += take;
            k += take;
            if (fill_ == n_) {
                segment();
                start_ = (start_ + n_ / 2) & mask;  // 50 % overlap
                fill_ = n_ / 2;
            }
        }
        if (j < n) fill_ = 0;  // a gap ends the segment: never bridged
        i = j + 1;
    }
}

void ErrorSpectrum::segment() {
    // The segment is buf_ from start_ on, wrapping around: two runs, in order.
    const std::size_t first = n_ - start_;
    const double* a = buf_.data() + start_;
    const double* b = buf_.data();
    // The mean in a pass that vectorises (summed in eight lanes, not in order: last bits only).
    double mean = 0;
#pragma omp simd reduction(+ : mean)
    for (std::size_t i = 0; i < first; ++i) mean += a[i];
#pragma omp simd reduction(+ : mean)
    for (std::size_t i = 0; i < start_; ++i) mean += b[i];
    mean /= static_cast<double>(n_);
    x_.resize(n_);
    double* x = x_.data();
    const double* w = window_.data();
#pragma omp simd
    for (std::size_t i = 0; i < first; ++i) x[i] = (a[i] - mean) * w[i];
#pragma omp simd
    for (std::size_t i = 0; i < start_; ++i) x[first + i] = (b[i] - mean) * w[first + i];
    fft_.accumulate(x_.data(), power_.data());
    ++segments_;
}

json ErrorSpectrum::to_json(double electrical_hz) const {
    json out{{"segments", segments_}, {"segment_samples", n_}, {"sample_rate_hz", fs_}, {"resolution_hz", fs_ / static_cast<double>(n_)},
             {"window", "hann"}, {"overlap", 0.5},
             {"amplitude_method", "Hann, RMS-averaged; local maxima corrected for scalloping by the two-bin ratio (Grandke)"},
             {"electrical_hz", electrical_hz > 0 ? json(electrical_hz) : json()}};
    json f = json::array(), order = json::array(), asd = json::array(), amp = json::array();
    if (segments_ == 0) {
        out["f_hz"] = f; out["order"] = order; out["asd_rad_per_sqrt_hz"] = asd; out["amplitude_rad"] = amp; out["decimation"] = 1;
        return out;
    }
    const std::size_t half = n_ / 2;
    const double segs = static_cast<double>(segments_);
    std::vector<double> mag(half + 1), a(half + 1), d(half + 1);
    for (std::size_t k = 0; k <= half; ++k) {
        mag[k] = std::sqrt(power_[k] / segs);  // RMS-averaged |X_k|
        // one-sided PSD: 2|X|^2/(fs * sum w^2), DC and Nyquist not doubled
        const double psd = (k == 0 || k == half ? 1.0 : 2.0) * power_[k] / segs / (fs_ * s2_);
        d[k] = std::sqrt(psd);
        a[k] = 2 * mag[k] / s1_;  // sinusoid of amplitude A centred in bin k: |X_k| = A*s1/2
    }
    // Scalloping: a tone delta bins off centre (0 <= delta < 1) gives |X_{k+1}|/|X_k| = (1+delta)/(2-delta)
    // for Hann, so delta = (2r-1)/(r+1) and A = 2|X_k|/s1 * pi*delta*(1-delta^2)/sin(pi*delta).
    for (std::size_t k = 2; k + 1 <= half; ++k) {
        if (mag[k] < mag[k - 1] || mag[k] < mag[k + 1] || mag[k] <= 0) continue;
        const double r = std::max(mag[k - 1], mag[k + 1]) / mag[k];
        const double delta = std::clamp((2 * r - 1) / (r + 1), 0.0, 0.999);
        const double corr = delta < 1e-9 ? 1.0 : kPi * delta * (1 - delta * delta) / std::sin(kPi * delta);
        a[k] *= corr;
    }
    const std::size_t bins = half;  // k = 1..half
    const std::size_t group = (bins + kMaxBins - 1) / kMaxBins;
    for (std::size_t k0 = 1; k0 <= half; k0 += group) {
        std::size_t best = k0;
        double dmax = 0;
        for (std::size_t k = k0; k < k0 + group && k <= half; ++k) {
            if (a[k] > a[best]) best = k;
            dmax = std::max(dmax, d[k]);
        }
        const double fk = static_cast<double>(best) * fs_ / static_cast<double>(n_);
        f.push_back(sig(fk, 8));
        order.push_back(electrical_hz > 0 ? json(sig(fk / electrical_hz)) : json());
        asd.push_back(sig(dmax));
        amp.push_back(sig(a[best]));
    }
    out["f_hz"] = std::move(f); out["order"] = std::move(order); out["asd_rad_per_sqrt_hz"] = std::move(asd);
    out["amplitude_rad"] = std::move(amp); out["decimation"] = group;
    return out;
}

}  // namespace fringe
