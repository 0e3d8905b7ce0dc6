#include "common.hpp"

#include "signal_gen/optics.hpp"

#include <algorithm>

namespace fringe::est {

bool Unwrapper::turns(const double* __restrict a, std::int64_t* __restrict k, std::size_t n) {
    if (n == 0) { k[0] = turns_; return true; }
    const double d0 = a[0] - (started_ ? prev_ : a[0]);  // the first sample of a run takes no step
    k[0] = (d0 < -kPi) - (d0 > kPi);
    std::int64_t any = k[0];
    for (std::size_t i = 1; i < n; ++i) {
        const double d = a[i] - a[i - 1];
        k[i] = static_cast<std::int64_t>(d < -kPi) - static_cast<std::int64_t>(d > kPi);
        any |= k[i];
    }
    started_ = true;
    prev_ = a[n - 1];
    if (any == 0) {
        k[0] = turns_;
        return true;
    }
    for (std::size_t i = 0; i < n; ++i) k[i] = turns_ += k[i];
    return false;
}

void Unwrapper::block(double* a, std::size_t n) {
    std::int64_t k[kTurnsTile];
    for (std::size_t off = 0; off < n; off += kTurnsTile) {
        const std::size_t m = std::min(kTurnsTile, n - off);
        double* __restrict x = a + off;
        if (turns(x, k, m)) {
            const double add = kTwoPi * static_cast<double>(k[0]);
            for (std::size_t i = 0; i < m; ++i) x[i] += add;
        } else {
            for (std::size_t i = 0; i < m; ++i) x[i] += kTwoPi * static_cast<double>(k[i]);
        }
    }
}

void Calibration::prepare() {
    if (!(amplitude_sin_v > 0) || !(amplitude_cos_v > 0))
        throw ConfigError("params.amplitude_sin_v", "calibration amplitudes must be positive");
    if (!(std::fabs(quadrature_error_rad) < kPi / 2))
        throw ConfigError("params.quadrature_error_rad", "must be within (-pi/2, pi/2)");
    inv_as_ = 1.0 / amplitude_sin_v;
    inv_ac_ = 1.0 / amplitude_cos_v;
    sin_d_ = std::sin(quadrature_error_rad);
    inv_cos_d_ = 1.0 / std::cos(quadrature_error_rad);
}

nlohmann::json Calibration::to_json() const {
    return {{"offset_sin_v", offset_sin_v}, {"offset_cos_v", offset_cos_v},
            {"amplitude_sin_v", amplitude_sin_v}, {"amplitude_cos_v", amplitude_cos_v},
            {"quadrature_error_rad", quadrature_error_rad}};
}

std::vector<ParamInfo> calibration_params() {
    const char* from = "default: from the encoder profile (zero / 1 without one)";
    return {
        {"offset_sin_v", "V", ParamType::Number, nullptr, -10, 10, {}, std::string("sin channel offset; ") + from},
        {"offset_cos_v", "V", ParamType::Number, nullptr, -10, 10, {}, std::string("cos channel offset; ") + from},
        {"amplitude_sin_v", "V", ParamType::Number, nullptr, 1e-9, 100, {}, std::string("sin fundamental amplitude; ") + from},
        {"amplitude_cos_v", "V", ParamType::Number, nullptr, 1e-9, 100, {}, std::string("cos fundamental amplitude; ") + from},
        {"quadrature_error_rad", "rad", ParamType::Number, nullptr, -1.5, 1.5, {}, std::string("cos channel phase error delta; ") + from},
    };
}

Calibration nominal_calibration(const std::optional<EncoderProfile>& encoder, const Params& p) {
    Calibration c;
    if (encoder) {
        const auto& e = *encoder;
        const double gs = 1.0 + e.lissajous.gain_mismatch / 2, gc = 1.0 - e.lissajous.gain_mismatch / 2;
        const double amp = e.fundamental_amplitude_v();
        const double dc = e.model == ModelKind::Diffraction ? e.vmax_v * e.aperture_w_rad / 2 : 0.0;
        c.offset_sin_v = gs * (dc - e.reference_v()) + e.lissajous.offset_sin_v;
        c.offset_cos_v = gc * (dc - e.reference_v()) + e.lissajous.offset_cos_v;
        c.amplitude_sin_v = gs * amp;
        c.amplitude_cos_v = gc * amp;
        c.quadrature_error_rad = e.lissajous.quadrature_error_rad;
    }
    if (auto v = p.optional_number("offset_sin_v")) c.offset_sin_v = *v;
    if (auto v = p.optional_number("offset_cos_v")) c.offset_cos_v = *v;
    if (auto v = p.optional_number("amplitude_sin_v")) c.amplitude_sin_v = *v;
    if (auto v = p.optional_number("amplitude_cos_v")) c.amplitude_cos_v = *v;
    if (auto v = p.optional_number("quadrature_error_rad")) c.quadrature_error_rad = *v;
    c.prepare();
    return c;
}

ParamInfo acquisition_param() {
    return {"acquisition_samples", "samples", ParamType::Integer, 200, 2, 1e7, {},
            "initialisation: line fit to the unwrapped atan2 over this many samples (output invalid meanwhile)"};
}

void LockMonitor::reset(const Calibration& told, double threshold_rad) {
    told_ = told;
    unwrap_.reset();
    threshold_ = threshold_rad;
    ref_ = diff_ = 0.0;
    events_ = invalid_ = 0;
    started_ = own_ = false;
    own_unwrap_.reset();
    own_start_ = 0;
    outliers_ = 0;
    radius2_ = 0;
    ring_sum_ = 0;
    ring_n_ = 0;
    ++frame_;
}

void LockMonitor::prepare(const double* s, const double* c, std::size_t n) {
    if (!own_) {
        pre_frame_ = ~std::uint64_t{0};
        return;
    }
    pre_.resize(n);
    double* w = pre_.data();
    const double sm = smid_, cm = cmid_, si = sinv_, ci = cinv_;
    for (std::size_t i = 0; i < n; ++i) w[i] = coarse_atan2((s[i] - sm) * si, (c[i] - cm) * ci);
    pre_frame_ = frame_;
}

double LockMonitor::reference(double s, double c) {
    if (own_) {
        // the frame changes only when a sample leaves the min/max box (rarely once running)
        if (s < smin_ || s > smax_ || c < cmin_ || c > cmax_) {
            // A sample beyond the box by more than half its range is an outlier (one glitch, a
            // 1e300): it does not widen the box, which it would spoil for good, and the
            // reference holds. Many of them (a leaky count over 32) mean the signal itself
            // changed (its amplitude jumped): the frame is learnt again, from the told one.
            const double hs = 0.5 * (smax_ - smin_), hc = 0.5 * (cmax_ - cmin_);
            if (s < smin_ - hs || s > smax_ + hs || c < cmin_ - hc || c > cmax_ + hc) {
                outliers_ += 2;
                if (outliers_ < 64) return ref_ = unwrap_.hold();
                outliers_ = 0;
                own_ = started_ = false;
                own_unwrap_.reset();
                own_start_ = 0;
                radius2_ = 0;
                ring_sum_ = 0;
                ring_n_ = 0;
                double sn, cn;
                told_.normalise(s, c, sn, cn);
                const double told = coarse_atan2(sn, cn);
                unwrap_.set(ref_ + wrap_pi(told - ref_));
                return reference(s, c);
            }
            smin_ = std::min(smin_, s); smax_ = std::max(smax_, s);
            cmin_ = std::min(cmin_, c); cmax_ = std::max(cmax_, c);
            own_frame();
        }
        if (outliers_ > 0) --outliers_;
        ref_ = unwrap_(coarse_atan2((s - smid_) * sinv_, (c - cmid_) * cinv_));
        return ref_;
    }
    double sn, cn;
    told_.normalise(s, c, sn, cn);
    // Before the own frame: a sample whose radius in the told frame is beyond 3x (or within
    // 1/3 of) the running radius is an outlier (a 5 V glitch, a dropout to 0 V): its atan2 can
    // lie anywhere, and one landing opposite the phase would unwrap a whole turn away. It holds
    // the reference and does not widen the min/max box (which it would spoil for good); a run
    // of them (the leaky count over 32) means the signal changed, and the radius is learnt again.
    const double r2 = sn * sn + cn * cn;
    if (!(radius2_ > 0)) radius2_ = r2;
    if (radius2_ > 0 && (r2 > 9.0 * radius2_ || r2 < radius2_ / 9.0)) {
        outliers_ += 2;
        if (outliers_ < 64) return ref_ = unwrap_.hold();
        outliers_ = 0;
        radius2_ = r2;
    } else {
        radius2_ += 0.03 * (r2 - radius2_);  // ~32 samples
        if (outliers_ > 0) --outliers_;
    }
    ref_ = unwrap_(coarse_atan2(sn, cn));
    if (!started_) {
        smin_ = smax_ = s;
        cmin_ = cmax_ = c;
        started_ = true;
    }
    // The own frame counts turns only while it is stable: a min/max that still grows by more
    // than 2 % of the range (the first cycle) restarts the count.
    const double grow = 0.02 * std::max(smax_ - smin_, cmax_ - cmin_);
    const bool moved = s < smin_ - grow || s > smax_ + grow || c < cmin_ - grow || c > cmax_ + grow;
    smin_ = std::min(smin_, s); smax_ = std::max(smax_, s);
    cmin_ = std::min(cmin_, c); cmax_ = std::max(cmax_, c);
    const double as = 0.5 * (smax_ - smin_), ac = 0.5 * (cmax_ - cmin_);
    if (moved || !(as > 0) || !(ac > 0)) {
        own_unwrap_.reset();
        own_start_ = 0;
        ring_sum_ = 0;
        ring_n_ = 0;
        return ref_;
    }
    const double xs = (s - 0.5 * (smax_ + smin_)) / as, xc = (c - 0.5 * (cmax_ + cmin_)) / ac;
    const double own = coarse_atan2(xs, xc);
    if (!own_unwrap_.started()) own_start_ = own;
    // A frame is a ring only if the samples lie on it: the mean of (r^2 - 1)^2 in the frame is
    // ~1e-3 on a Lissajous figure and 0.3-0.7 for noise filling its own min/max box (an encoder
    // at standstill, whose atan2 in that box turns at random and would count turns).
    const double r2m1 = xs * xs + xc * xc - 1.0;
    ring_sum_ += r2m1 * r2m1;
    ++ring_n_;
    // (never on a held sample: the own frame's turn count would continue from a spike's phase)
    if (std::fabs(own_unwrap_(own) - own_start_) > 2 * kTwoPi && !unwrap_.holding() && ring_sum_ < 0.15 * ring_n_) {
        // two turns in a stable frame: switch, continuing the told frame's turn count
        own_ = true;
        own_frame();
        unwrap_.set(ref_ + wrap_pi(own - ref_));
    }
    return ref_;
}

nlohmann::json LockMonitor::to_json() const {
    return {{"events", events_}, {"samples_invalid", invalid_}, {"threshold_rad", threshold_},
            {"reference", own_ ? "own min/max calibration" : "told calibration"}};
}

ParamInfo LockMonitor::threshold_param() {
    return {"lock_threshold_rad", "rad", ParamType::Number, 1.0, 0.05, 3.0, {},
            "loss of lock: the phase left this band around the unwrapped atan2 of the samples (low-passed over ~8 samples); "
            "the output is then invalid and the tracker re-acquires from atan2 (state: loss_of_lock)"};
}

void Acquisition::reset(std::size_t n, double sample_rate_hz, const Calibration& cal) {
    n_ = n < 2 ? 2 : n;
    k_ = m_ = 0;
    fs_ = sample_rate_hz;
    cal_ = cal;
    unwrap_.reset();
    first_ = last_ = sk_ = skk_ = sy_ = sky_ = 0.0;
}

bool Acquisition::add(double s, double c) {
    double sn, cn;
    cal_.normalise(s, c, sn, cn);
    last_ = unwrap_(fast_atan2(sn, cn));
    if (m_ == 0) first_ = last_;
    const double k = static_cast<double>(k_), y = last_ - first_;
    sk_ += k; skk_ += k * k; sy_ += y; sky_ += k * y;
    ++m_;
    ++k_;
    return k_ < n_ ? false : fit();
}

bool Acquisition::skip() {
    ++k_;
    return k_ < n_ ? false : fit();
}

// The least-squares line over the samples fitted (skipped ones are missing data), evaluated
// at the last sample's index.
bool Acquisition::fit() {
    const double m = static_cast<double>(m_), last_k = static_cast<double>(n_) - 1.0;
    const double den = m * skk_ - sk_ * sk_;
    if (m_ < 2 || !(den > 0)) {
        theta_ = last_;
        omega_ = 0.0;
        return true;
    }
    const double slope = (m * sky_ - sk_ * sy_) / den;  // rad/sample
    const double icpt = (sy_ - slope * sk_) / m;
    theta_ = first_ + icpt + slope * last_k;
    omega_ = slope * fs_;
    return true;
}

}  // namespace fringe::est
