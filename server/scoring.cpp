#include "scoring.hpp"

#include "signal_gen/fastmath.hpp"

#include <algorithm>
#include <cmath>

namespace fringe {

Scorer::Scorer(double settle_s, double lock_threshold_rad) : settle_s_(settle_s), lock_thr_(lock_threshold_rad) {
    X_.resize(4096, 2 * kHarmonics + 1);
    y_.resize(4096);
    XtX_.setZero();
    Xty_.setZero();
}

void Scorer::add(std::size_t n, const double* t, const double* th_true, const double* om_true,
                 const double* th_hat, const double* om_hat, const std::uint8_t* valid) {
    if (n && !have_t0_) { t0_ = t[0]; have_t0_ = true; }
    for (std::size_t i = 0; i < n; ++i) {
        ++m_.samples;
        const double e_raw = th_hat[i] - th_true[i];
        const bool ok = valid[i] && std::isfinite(e_raw);
        // lock: every sample after lock_time has |wrap(e)| <= threshold and is valid
        if (!ok || std::fabs(wrap_pi(e_raw)) > lock_thr_) { locked_now_ = false; last_unlocked_t_ = t[i]; }
        else if (!locked_now_) { locked_now_ = true; first_t_after_ = t[i]; }
        if (t[i] - t0_ < settle_s_) continue;
        if (!ok) { ++m_.invalid_after_settle; continue; }
        if (om_true && om_hat) {
            const double d = om_hat[i] - om_true[i];
            ++om_n_;
            const double delta = d - om_mean_;
            om_mean_ += delta / static_cast<double>(om_n_);
            om_m2_ += delta * (d - om_mean_);
        }
        if (om_true) sum_omega_true_ += om_true[i];
        if (!decided_) {
            pending_e_.push_back(e_raw);
            pending_th_.push_back(th_true[i]);
            if (pending_e_.size() >= kMedianWindow) {
                std::vector<double> tmp = pending_e_;
                std::nth_element(tmp.begin(), tmp.begin() + static_cast<long>(tmp.size() / 2), tmp.end());
                offset_rad_ = kTwoPi * std::round(tmp[tmp.size() / 2] / kTwoPi);
                decided_ = true;
                for (std::size_t k = 0; k < pending_e_.size(); ++k) accumulate(pending_e_[k], pending_th_[k]);
                pending_e_.clear(); pending_e_.shrink_to_fit();
                pending_th_.clear(); pending_th_.shrink_to_fit();
            }
        } else {
            accumulate(e_raw, th_true[i]);
        }
    }
}

void Scorer::accumulate(double e_raw, double th) {
    const double e = e_raw - offset_rad_;
    ++m_.scored;
    const double d = e - mean_;
    mean_ += d / static_cast<double>(m_.scored);
    m2_ += d * (e - mean_);
    min_e_ = std::min(min_e_, e);
    max_e_ = std::max(max_e_, e);
    if (std::fabs(e) > kPi) ++m_.slipped_samples;
    // harmonic regressors by the Chebyshev recurrence from one sincos
    const double s1 = std::sin(th), c1 = std::cos(th);
    double cm = c1, sm = s1;
    X_(static_cast<long>(rows_), 0) = 1.0;
    for (int k = 1; k <= kHarmonics; ++k) {
        X_(static_cast<long>(rows_), 2 * k - 1) = cm;
        X_(static_cast<long>(rows_), 2 * k) = sm;
        const double cn = cm * c1 - sm * s1;
        sm = sm * c1 + cm * s1;
        cm = cn;
    }
    y_(static_cast<long>(rows_)) = e;
    if (++rows_ == static_cast<std::size_t>(X_.rows())) flush_harmonics();
}

void Scorer::flush_harmonics() {
    if (!rows_) return;
    const auto X = X_.topRows(static_cast<long>(rows_));
    XtX_.noalias() += X.transpose() * X;
    Xty_.noalias() += X.transpose() * y_.head(static_cast<long>(rows_));
    rows_ = 0;
}

ErrorMetrics Scorer::finish() {
    if (!decided_) {
        if (!pending_e_.empty()) {
            std::vector<double> tmp = pending_e_;
            std::nth_element(tmp.begin(), tmp.begin() + static_cast<long>(tmp.size() / 2), tmp.end());
            offset_rad_ = kTwoPi * std::round(tmp[tmp.size() / 2] / kTwoPi);
        }
        decided_ = true;
        for (std::size_t k = 0; k < pending_e_.size(); ++k) accumulate(pending_e_[k], pending_th_[k]);
        pending_e_.clear();
        pending_th_.clear();
    }
    flush_harmonics();
    ErrorMetrics m = m_;
    m.removed_cycles = offset_rad_ / kTwoPi;
    if (m.scored) {
        m.mean_rad = mean_;
        m.std_rad = m.scored > 1 ? std::sqrt(m2_ / static_cast<double>(m.scored - 1)) : 0.0;
        m.rms_rad = std::sqrt(mean_ * mean_ + m2_ / static_cast<double>(m.scored));
        m.max_abs_rad = std::max(std::fabs(min_e_), std::fabs(max_e_));
        m.max_dev_rad = std::max(max_e_ - mean_, mean_ - min_e_);
        // Harmonics: solve the normal equations when the regressors are well conditioned
        // (a run covering at least a few electrical cycles).
        Eigen::LDLT<Eigen::Matrix<double, 2 * kHarmonics + 1, 2 * kHarmonics + 1>> ldlt(XtX_);
        const auto d = ldlt.vectorD();
        if (ldlt.info() == Eigen::Success && ldlt.isPositive() && d.minCoeff() > 1e-9 * d.maxCoeff()) {
            const auto b = ldlt.solve(Xty_);
            for (int k = 1; k <= kHarmonics; ++k) {
                const double a = b(2 * k - 1), c = b(2 * k);
                m.harmonics.push_back({k, std::hypot(a, c), std::atan2(c, a)});
            }
        }
        if (om_n_) {
            m.have_rate = true;
            m.omega_error_mean_rad_s = om_mean_;
            m.omega_error_std_rad_s = om_n_ > 1 ? std::sqrt(om_m2_ / static_cast<double>(om_n_ - 1)) : 0.0;
        }
        const double mean_omega = sum_omega_true_ / static_cast<double>(m.scored);
        if (std::fabs(mean_omega) > 1e-9) m.lag_s = -mean_ / mean_omega;
    }
    if (locked_now_) m.lock_time_s = first_t_after_ - t0_;
    return m;
}

nlohmann::json angle_units(double rad, int lines) {
    nlohmann::json j{{"rad", rad}, {"percent_period", rad / kTwoPi * 100.0}};
    j["arcsec_mech"] = lines > 0 ? nlohmann::json(rad / lines * (180.0 / kPi) * 3600.0) : nlohmann::json();
    return j;
}

nlohmann::json to_json(const ErrorMetrics& m, int lines) {
    nlohmann::json j{{"samples", m.samples}, {"scored", m.scored}, {"invalid_after_settle", m.invalid_after_settle},
                     {"removed_cycles", m.removed_cycles}, {"slipped_samples", m.slipped_samples},
                     {"mean", angle_units(m.mean_rad, lines)}, {"std", angle_units(m.std_rad, lines)},
                     {"rms", angle_units(m.rms_rad, lines)}, {"max_abs", angle_units(m.max_abs_rad, lines)},
                     {"max_dev", angle_units(m.max_dev_rad, lines)}};
    auto h = nlohmann::json::array();
    for (const auto& x : m.harmonics)
        h.push_back({{"order", x.order}, {"amplitude", angle_units(x.amplitude_rad, lines)}, {"phase_rad", x.phase_rad}});
    j["harmonics"] = h;
    if (m.have_rate) j["omega_error"] = {{"mean_rad_s", m.omega_error_mean_rad_s}, {"std_rad_s", m.omega_error_std_rad_s}};
    j["lag_s"] = m.lag_s ? nlohmann::json(*m.lag_s) : nlohmann::json();
    j["lock_time_s"] = m.lock_time_s ? nlohmann::json(*m.lock_time_s) : nlohmann::json();
    return j;
}

}  // namespace fringe
