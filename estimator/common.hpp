// Building blocks shared by the estimators: a vectorisable atan2, exact unwrapping, the
// nominal Lissajous calibration (MODEL.md 4.1) and the acquisition that initialises the
// trackers (MODEL.md 4.3, "Initialisation").
#pragma once

#include "estimator.hpp"
#include "signal_gen/fastmath.hpp"

#include <cmath>
#include <cstdint>

namespace fringe::est {

// The EKFs' outlier gate: a sample whose normalised innovation squared (2 degrees of freedom)
// exceeds this may be an outlier (ekf.cpp, ekf_auto.cpp).
constexpr double kOutlierNis = 1e4;

// atan(u)/u = 1 + sum_{k=1}^{11} c_k z^k (z = u^2) on |u| <= tan(pi/8): the Chebyshev
// interpolant of (atan(u)/u - 1)/z at 2000 nodes, its series taken to 44 terms in 80-bit
// arithmetic and the change of basis done in exact rationals; c_1 = -1/3 and c_2 = 1/5 to
// 1e-13, the rest drift from the Taylor coefficients -1/7, 1/9, ... as the fit spreads its
// error. Approximation error below 8e-18 relative with these doubles (0.07 ulp); the Taylor
// series needs terms to u^37 (18 instead of 11) for 3e-17.
inline constexpr double kAtanMinimax[12] = {
    1.0,
    -0.3333333333333333,
    0.19999999999995657,
    -0.14285714284692488,
    0.11111111017170303,
    -0.09090904650118907,
    0.07692184749286707,
    -0.06664532006984204,
    0.058583168984966655,
    -0.05086279617750602,
    0.0392543655618529,
    -0.019203302301598873,
};

// atan2 without libm: octant reduction to t = min/max in [0, 1], then to |u| <= tan(pi/8)
// via atan(t) = pi/4 + atan((t-1)/(t+1)), then the polynomial above. Branch-free, so GCC
// vectorises it over a block; within 2 ulp of std::atan2 (tested). atan2(0, 0) = 0.
// The polynomial in z = u^2 is evaluated with std::fma: its terms from z^3 on by Estrin's
// scheme (a tree of depth 4) and added to the first three (Horner) by one fma with z^3, so
// the rounding of the small low-order terms is as in a plain Horner chain. A Horner chain of
// 19 multiply-adds without fma kept the block loop bound by latency. fma is correctly rounded
// (IEEE 754), so the result is the same on every machine, with or without hardware FMA.
// num / (den > 0 ? den : 1) rather than a select after the division: 0/1 is the same 0 at
// atan2(0, 0), and the select does not propagate as a mask through every later step.
inline double fast_atan2(double y, double x) {
    constexpr double kTanPi8 = 0.41421356237309504880;
    const double ax = std::fabs(x), ay = std::fabs(y);
    const double mx = ax > ay ? ax : ay, mn = ax > ay ? ay : ax;
    const bool big = mn > kTanPi8 * mx;
    const double num = big ? mn - mx : mn, den = big ? mn + mx : mx;
    const double u = num / (den > 0.0 ? den : 1.0);
    const double z = u * u, z2 = z * z, z4 = z2 * z2, z8 = z4 * z4;
    // q = c3 + c4 z + ... + c11 z^8 (kAtanMinimax[3..11])
    constexpr const double* c = kAtanMinimax;
    const double e0 = std::fma(c[4], z, c[3]), e1 = std::fma(c[6], z, c[5]);
    const double e2 = std::fma(c[8], z, c[7]), e3 = std::fma(c[10], z, c[9]);
    const double f0 = std::fma(e1, z2, e0), f1 = std::fma(e3, z2, e2);
    const double q = std::fma(c[11], z8, std::fma(f1, z4, f0));
    const double low = std::fma(std::fma(c[2], z, c[1]), z, 1.0);  // 1 + c1 z + c2 z^2
    const double p = std::fma(z * z2, q, low);                      // atan(u)/u
    double a = big ? std::fma(u, p, kPi / 4) : u * p;
    a = ay > ax ? kPi / 2 - a : a;
    a = x < 0.0 ? kPi - a : a;
    return std::copysign(a, y);  // a >= 0 here; copysign keeps atan2(-0, x) = -0 or -pi
}

// The same reduction with the series cut at u^9: |error| < tan(pi/8)^11/11 < 6e-6 rad. For
// references that only have to be right to well within a radian (the loss-of-lock guard).
inline double coarse_atan2(double y, double x) {
    constexpr double kTanPi8 = 0.41421356237309504880;
    const double ax = std::fabs(x), ay = std::fabs(y);
    const double mx = ax > ay ? ax : ay, mn = ax > ay ? ay : ax;
    const bool big = mn > kTanPi8 * mx;
    const double num = big ? mn - mx : mn, den = big ? mn + mx : mx;
    const double u = den > 0.0 ? num / den : 0.0;
    const double z = u * u, z2 = z * z;
    // 1 - z/3 + z^2/5 - z^3/7 + z^4/9 in two levels of fma: it sits on every EKF sample's path
    const double p = std::fma(std::fma(1.0 / 9.0, z2, std::fma(-1.0 / 7.0, z, 1.0 / 5.0)), z2, std::fma(-1.0 / 3.0, z, 1.0));
    double a = big ? std::fma(u, p, kPi / 4) : u * p;
    a = ay > ax ? kPi / 2 - a : a;
    a = x < 0.0 ? kPi - a : a;
    return std::copysign(a, y);
}

// Unwraps a wrapped phase sequence exactly: theta = a + 2*pi*turns with an integer turn
// count, so no rounding accumulates over 10^8 samples (a running float sum would).
class Unwrapper {
public:
    void reset() { started_ = false; turns_ = 0; prev_ = 0.0; }
    bool started() const { return started_; }
    double operator()(double a) {
        if (started_) {
            const double d = a - prev_;
            turns_ += (d < -kPi) - (d > kPi);
        }
        started_ = true;
        prev_ = a;
        return a + kTwoPi * static_cast<double>(turns_);
    }
    // The same as calling operator() on a[0], ..., a[n-1] in turn, in place, to the bit, in
    // three passes per tile: the turn steps of all samples (compares, vectorised), their
    // running sum (integer adds: the only serial part), then the multiples of 2 pi added
    // (vectorised). Sample by sample the state round trip through memory cost more than the
    // atan2 before it.
    void block(double* a, std::size_t n);
    // The turn counts operator() would add (2 pi times) to a[0], ..., a[n-1], n <= kTurnsTile,
    // advancing the state as it would: true when one count holds for all of them (k[0], the
    // common case at hundreds of samples per turn: no serial pass at all), else each in k[i].
    static constexpr std::size_t kTurnsTile = 128;
    bool turns(const double* a, std::int64_t* k, std::size_t n);
    // Re-anchor so that the next call continues from an unwrapped value theta.
    void set(double theta) {
        const double a = wrap_pi(theta);
        turns_ = static_cast<std::int64_t>(std::llround((theta - a) / kTwoPi));
        prev_ = a;
        started_ = true;
    }

private:
    bool started_ = false;
    std::int64_t turns_ = 0;
    double prev_ = 0.0;
};

// Lissajous calibration (MODEL.md 4.1): s = o_s + A_s sin(theta),
// c = o_c + A_c cos(theta + delta). normalise() returns (sin theta, cos theta) estimates.
struct Calibration {
    double offset_sin_v = 0.0, offset_cos_v = 0.0;
    double amplitude_sin_v = 1.0, amplitude_cos_v = 1.0;
    double quadrature_error_rad = 0.0;

    void normalise(double s, double c, double& sn, double& cn) const {
        sn = (s - offset_sin_v) * inv_as_;
        cn = ((c - offset_cos_v) * inv_ac_ + sn * sin_d_) * inv_cos_d_;
    }
    void prepare();  // after setting fields
    // The constants of normalise(), for loops that hoist them into registers.
    struct Coeffs { double os, oc, inv_as, inv_ac, sin_d, inv_cos_d; };
    Coeffs coeffs() const { return {offset_sin_v, offset_cos_v, inv_as_, inv_ac_, sin_d_, inv_cos_d_}; }
    nlohmann::json to_json() const;

private:
    double inv_as_ = 1.0, inv_ac_ = 1.0, sin_d_ = 0.0, inv_cos_d_ = 1.0;
};

// The profile's nominal calibration (fundamental amplitude, front-end DC, Lissajous errors),
// or zero offsets and unit amplitudes without a profile; any of the parameters
// offset_sin_v, offset_cos_v, amplitude_sin_v, amplitude_cos_v, quadrature_error_rad that is
// given overrides it.
Calibration nominal_calibration(const std::optional<EncoderProfile>& encoder, const Params& p);
std::vector<ParamInfo> calibration_params();

// Tracker initialisation: atan2 of the calibrated samples, unwrapped, and a least-squares
// line over the first n samples gives the phase at the last of them and the rate.
class Acquisition {
public:
    void reset(std::size_t n, double sample_rate_hz, const Calibration& cal);
    // Feed one sample; returns true when the fit is complete (theta_rad/omega_rad_s valid).
    bool add(double s, double c);
    // A sample known to be an outlier: it counts in time, not in the fit.
    bool skip();
    double theta_rad() const { return theta_; }
    double omega_rad_s() const { return omega_; }
    double last_atan2_rad() const { return last_; }
    bool done() const { return k_ >= n_; }
    std::size_t samples() const { return n_; }
    std::size_t used() const { return m_; }  // samples in the fit (not skipped)

private:
    bool fit();
    std::size_t n_ = 200, k_ = 0, m_ = 0;
    double fs_ = 1.0;
    Calibration cal_;
    Unwrapper unwrap_;
    double first_ = 0.0, last_ = 0.0, sk_ = 0.0, skk_ = 0.0, sy_ = 0.0, sky_ = 0.0;
    double theta_ = 0.0, omega_ = 0.0;
};
ParamInfo acquisition_param();

// An unwrap that one wild sample cannot move by a turn (the loss-of-lock reference's). Plain
// unwrapping takes each sample's atan2 within pi of the last: a glitch landing opposite the
// phase, then the next true sample, can add 2*pi (a 1.3 V spike on a 1.1 V signal every 100
// samples slipped the reference, and re-anchored trackers a turn away, marked valid). Here the
// phase is predicted from the last accepted one and the mean step per sample; a sample more
// than pi/2 off the prediction is held (the prediction is returned) up to 3 in a row, after
// which it is the motion and accepted.
class RobustUnwrap {
public:
    void reset() { started_ = false; stepped_ = false; acc_ = acc_w_ = step_ = 0.0; held_ = 0; }
    bool started() const { return started_; }
    double operator()(double a) {  // a: this sample's atan2 (rad, wrapped)
        if (!started_) {
            started_ = true;
            acc_ = acc_w_ = a;
            return acc_;
        }
        const double pred = acc_ + (1 + held_) * step_;
        // wrap(a - pred) from the wrapped prediction: acc_w_ is acc_ wrapped, kept alongside it
        // (std::remainder on the unwrapped phase every sample cost the EKFs 10 % of their rate)
        double dev = a - (acc_w_ + (1 + held_) * step_);
        if (std::fabs(dev) > 3 * kPi) dev = wrap_pi(dev);
        else if (dev > kPi) dev -= kTwoPi;
        else if (dev <= -kPi) dev += kTwoPi;
        if (stepped_ && std::fabs(dev) > 0.5 * kPi && held_ < 3) {
            ++held_;
            return pred;
        }
        const double next = pred + dev;
        const double step = (next - acc_) / (1 + held_);
        step_ = stepped_ ? step_ + 0.125 * (step - step_) : step;
        stepped_ = true;
        held_ = 0;
        acc_ = next;
        acc_w_ = a;  // next, wrapped: a itself
        return acc_;
    }
    // Hold this sample (an outlier found otherwise): the prediction.
    double hold() { return started_ ? acc_ + (++held_) * step_ : acc_; }
    bool holding() const { return held_ > 0; }  // the last sample was held
    // Re-anchor so that the next call continues from an unwrapped value theta.
    void set(double theta) {
        acc_ = theta;
        acc_w_ = wrap_pi(theta);
        held_ = 0;
        started_ = true;
    }

private:
    bool started_ = false, stepped_ = false;
    double acc_ = 0.0, acc_w_ = 0.0, step_ = 0.0;  // last accepted phase (rad; wrapped), mean step per sample (rad)
    int held_ = 0;
};

// Loss-of-lock guard (issue 13: nothing diverges silently). An independent reference phase,
// the unwrapped atan2 of the samples, runs beside a tracker on every sample. A cycle slip or
// a divergence moves the tracker's phase away from it by up to 2*pi, so it must leave a band
// of threshold_rad around it: the difference, low-passed over ~8 samples so one noisy sample
// cannot trip it, is checked every sample. On loss the caller marks the sample invalid,
// counts it and re-acquires, anchoring the new phase to the reference's turn count
// (anchor()), so a re-acquired tracker does not carry a slipped cycle either.
//
// The reference does not trust what the tracker was told: it starts with the told
// calibration, and once the signal has gone round twice in the frame of its own per-channel
// min/max (offset = mid-range, amplitude = half range) it switches to that frame (a wrong
// profile, e.g. a diffraction model told about an ideal encoder, cannot fool it). The band
// allows for the reference's own error on distorted signals (~0.2 rad at 10 % duty-cycle
// error, |o|/A for offsets o).
class LockMonitor {
public:
    void reset(const Calibration& told, double threshold_rad);
    // Every sample, before check(); returns the unwrapped reference phase (rad).
    double reference(double s, double c);
    // The same, for sample i of a block given to prepare() first: the own frame's atan2 of
    // the whole block is computed there in one vectorised pass, and taken here while the
    // frame has not changed since (the same numbers as reference(): the same operations,
    // fma correctly rounded in a vector as in a scalar).
    void prepare(const double* s, const double* c, std::size_t n);
    double reference_at(std::size_t i, double s, double c) {
        if (own_ && pre_frame_ == frame_ && i < pre_.size() && !(s < smin_ || s > smax_ || c < cmin_ || c > cmax_)) {
            if (outliers_ > 0) --outliers_;
            return ref_ = unwrap_(pre_[i]);
        }
        return reference(s, c);
    }
    // A tracker output; false when it left the band (one event per loss, until rearm()).
    bool check(double theta_rad) {
        diff_ += (theta_rad - ref_ - diff_) * 0.125;
        if (!(std::fabs(diff_) <= threshold_)) {
            ++events_;
            return false;
        }
        return true;
    }
    // The reference's turn count given to a re-acquired phase.
    double anchor(double theta_rad) const { return ref_ + wrap_pi(theta_rad - ref_); }
    void rearm() { diff_ = 0.0; }
    // A loss the tracker found itself (its updates no longer fit the signal).
    void declare_loss() { ++events_; }
    // The last sample was an outlier to the reference (held, not taken in).
    bool outlier() const { return unwrap_.holding(); }
    void count_invalid() { ++invalid_; }
    long long events() const { return events_; }
    long long samples_invalid() const { return invalid_; }
    nlohmann::json to_json() const;
    static ParamInfo threshold_param();

private:
    Calibration told_;
    RobustUnwrap unwrap_;
    double threshold_ = 1.0, ref_ = 0.0, diff_ = 0.0;
    long long events_ = 0, invalid_ = 0;
    // own frame: per-channel min/max, and how far the phase has gone round in it
    double smin_ = 0, smax_ = 0, cmin_ = 0, cmax_ = 0, own_start_ = 0;
    double smid_ = 0, cmid_ = 0, sinv_ = 1, cinv_ = 1;  // the own frame: centres, 1/half-ranges
    double ring_sum_ = 0;  // sum of (r^2 - 1)^2 in the candidate frame since its count began
    double ring_n_ = 0;
    std::uint64_t frame_ = 0, pre_frame_ = ~std::uint64_t{0};  // the own frame's version; prepare()'s
    std::vector<double> pre_;  // prepare()'s atan2 in the own frame, per sample of the block
    void own_frame() {
        ++frame_;
        smid_ = 0.5 * (smax_ + smin_);
        cmid_ = 0.5 * (cmax_ + cmin_);
        sinv_ = 2.0 / (smax_ - smin_);
        cinv_ = 2.0 / (cmax_ - cmin_);
    }
    Unwrapper own_unwrap_;
    bool started_ = false, own_ = false;
    int outliers_ = 0;  // leaky count of samples far outside the own frame's box (or the told radius)
    double radius2_ = 0;  // running squared radius in the told frame (0: none yet)
};

}  // namespace fringe::est
