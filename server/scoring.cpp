#include "scoring.hpp"

#include "signal_gen/fastmath.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>

namespace fringe {

Scorer::Scorer(double settle_s) : Scorer(ScoringOptions{settle_s}) {}

Scorer::Scorer(ScoringOptions o) : o_(o) {
    o_.max_harmonic = std::clamp(o_.max_harmonic, 1, kMaxHarmonic);
    const std::size_t m = 2 * static_cast<std::size_t>(o_.max_harmonic) + 1;
    sum_cos_.assign(m, 0.0);
    sum_sin_.assign(m, 0.0);
    sum_ecos_.assign(static_cast<std::size_t>(o_.max_harmonic) + 1, 0.0);
    sum_esin_.assign(static_cast<std::size_t>(o_.max_harmonic) + 1, 0.0);
    bins_.assign(kAngleBins, 0);
    m_.harmonics_requested = o_.max_harmonic;
}

void Scorer::add(std::size_t n, const double* t, const double* th_true, const double* om_true,
                 const double* th_hat, const double* om_hat, const std::uint8_t* valid) {
    if (n && !have_t0_) { t0_ = t[0]; have_t0_ = true; }
    std::vector<double> e_raw, th;
    std::vector<std::uint8_t> ok;
    e_raw.reserve(n); th.reserve(n); ok.reserve(n);
    for (std::size_t i = 0; i < n; ++i) {
        ++m_.samples;
        const double e = th_hat[i] - th_true[i];
        const bool good = valid[i] && std::isfinite(e);
        // lock: every sample after lock_time has |wrap(e)| <= threshold and is valid
        if (!good || std::fabs(wrap_pi(e)) > o_.lock_threshold_rad) locked_now_ = false;
        else if (!locked_now_) { locked_now_ = true; first_t_after_ = t[i]; }
        if (t[i] - t0_ < o_.settle_s) continue;
        ++m_.after_settle;
        e_raw.push_back(good ? e : 0.0);
        th.push_back(th_true[i]);
        ok.push_back(good ? 1 : 0);
        if (!good) { ++m_.invalid_after_settle; continue; }
        if (om_true && std::isfinite(om_true[i])) {
            sum_omega_true_ += om_true[i];
            sum_abs_omega_true_ += std::fabs(om_true[i]);
            ++n_omega_true_;
            if (om_hat) {
                const double d = om_hat[i] - om_true[i];
                if (!std::isfinite(d)) { ++m_.omega_nonfinite; continue; }
                ++om_n_;
                const double delta = d - om_mean_;
                om_mean_ += delta / static_cast<double>(om_n_);
                om_m2_ += delta * (d - om_mean_);
            }
        }
    }
    if (e_raw.empty()) return;
    if (decided_) return process(e_raw.size(), e_raw.data(), th.data(), ok.data());
    pending_e_.insert(pending_e_.end(), e_raw.begin(), e_raw.end());
    pending_th_.insert(pending_th_.end(), th.begin(), th.end());
    pending_ok_.insert(pending_ok_.end(), ok.begin(), ok.end());
    if (static_cast<std::size_t>(std::count(pending_ok_.begin(), pending_ok_.end(), 1)) >= kMedianWindow) decide();
}

void Scorer::decide() {
    std::vector<double> tmp;
    for (std::size_t k = 0; k < pending_e_.size(); ++k)
        if (pending_ok_[k]) tmp.push_back(pending_e_[k]);
    if (!tmp.empty()) {
        std::nth_element(tmp.begin(), tmp.begin() + static_cast<long>(tmp.size() / 2), tmp.end());
        offset_rad_ = kTwoPi * std::round(tmp[tmp.size() / 2] / kTwoPi);
    }
    decided_ = true;
    if (!pending_e_.empty()) process(pending_e_.size(), pending_e_.data(), pending_th_.data(), pending_ok_.data());
    pending_e_ = {};
    pending_th_ = {};
    pending_ok_ = {};
}

void Scorer::process(std::size_t n, const double* e_raw, const double* th, const std::uint8_t* ok) {
    e_.assign(n, 0.0);
    c1_.clear(); s1_.clear();
    std::vector<double> es;  // the scored errors, compacted, for the harmonic sums
    es.reserve(n);
    for (std::size_t i = 0; i < n; ++i) {
        if (!ok[i]) continue;
        const double e = e_raw[i] - offset_rad_;
        e_[i] = e;
        ++m_.scored;
        const double d = e - mean_;
        mean_ += d / static_cast<double>(m_.scored);
        m2_ += d * (e - mean_);
        min_e_ = std::min(min_e_, e);
        max_e_ = std::max(max_e_, e);
        if (std::fabs(e) > kPi) ++m_.slipped_samples;
        if (have_last_th_) m_.cycles_scored += std::fabs(th[i] - last_th_) / kTwoPi;
        last_th_ = th[i];
        have_last_th_ = true;
        double s, c;
        fast_sincos(th[i], s, c);
        s1_.push_back(s);
        c1_.push_back(c);
        es.push_back(e);
        const double w = th[i] - kTwoPi * std::floor(th[i] / kTwoPi);  // [0, 2*pi)
        const auto b = std::min<long>(kAngleBins - 1, static_cast<long>(w / kTwoPi * kAngleBins));
        ++bins_[static_cast<std::size_t>(b)];
    }
    // Harmonic sums by the Chebyshev recurrence, one order at a time over the block (vectorises).
    const std::size_t ns = es.size();
    if (ns) {
        cm_.assign(c1_.begin(), c1_.end());
        sm_.assign(s1_.begin(), s1_.end());
        sum_cos_[0] += static_cast<double>(ns);
        for (std::size_t i = 0; i < ns; ++i) sum_e_ += es[i];
        const int M = 2 * o_.max_harmonic;
        for (int m = 1; m <= M; ++m) {
            double sc = 0, ss = 0, sec = 0, ses = 0;
            if (m <= o_.max_harmonic) {
                for (std::size_t i = 0; i < ns; ++i) { sc += cm_[i]; ss += sm_[i]; sec += es[i] * cm_[i]; ses += es[i] * sm_[i]; }
                sum_ecos_[static_cast<std::size_t>(m)] += sec;
                sum_esin_[static_cast<std::size_t>(m)] += ses;
            } else {
                for (std::size_t i = 0; i < ns; ++i) { sc += cm_[i]; ss += sm_[i]; }
            }
            sum_cos_[static_cast<std::size_t>(m)] += sc;
            sum_sin_[static_cast<std::size_t>(m)] += ss;
            if (m == M) break;
            for (std::size_t i = 0; i < ns; ++i) {
                const double cn = cm_[i] * c1_[i] - sm_[i] * s1_[i];
                sm_[i] = sm_[i] * c1_[i] + cm_[i] * s1_[i];
                cm_[i] = cn;
            }
        }
    }
    if (sink_) sink_(n, e_.data(), ok);
}

ErrorMetrics Scorer::finish() {
    if (!decided_) decide();
    ErrorMetrics m = m_;
    m.removed_cycles = offset_rad_ / kTwoPi;
    if (n_omega_true_) m.mean_abs_omega_true_rad_s = sum_abs_omega_true_ / static_cast<double>(n_omega_true_);
    if (m.scored) {
        m.mean_rad = mean_;
        m.std_rad = m.scored > 1 ? std::sqrt(m2_ / static_cast<double>(m.scored - 1)) : 0.0;
        m.rms_rad = std::sqrt(mean_ * mean_ + m2_ / static_cast<double>(m.scored));
        m.max_abs_rad = std::max(std::fabs(min_e_), std::fabs(max_e_));
        m.max_dev_rad = std::max(max_e_ - mean_, mean_ - min_e_);
        // Harmonics. A function sampled at N distinct angles determines at most N/2 of them;
        // a quarter keeps the fit well conditioned. Fewer than one whole cycle leaves part of
        // the circle unseen, where no order can be told apart from the others.
        const auto covered = static_cast<int>(std::count_if(bins_.begin(), bins_.end(), [](std::uint32_t c) { return c > 0; }));
        if (m.cycles_scored < 1.0) {
            m.harmonics_note = "the scored samples cover " + std::to_string(m.cycles_scored).substr(0, 5) +
                               " electrical cycles: harmonics need at least one whole cycle to be told apart";
        } else {
            // The highest order the visited angles support: start from a quarter of the bins
            // visited and lower it until the normal equations are well conditioned (samples
            // at a few distinct angles, as with synchronous sampling, support only a few).
            // Never more unknowns than a quarter of the scored samples, so the fit is not of noise.
            const auto by_samples = static_cast<int>(std::min<std::uint64_t>(64, (m.scored / 4 > 1 ? (m.scored / 4 - 1) / 2 : 0)));
            const int K0 = std::min({o_.max_harmonic, std::max(1, covered / 4), std::max(1, by_samples)});
            auto C = [&](int k) { return sum_cos_[static_cast<std::size_t>(std::abs(k))]; };
            auto S = [&](int k) { return k < 0 ? -sum_sin_[static_cast<std::size_t>(-k)] : sum_sin_[static_cast<std::size_t>(k)]; };
            for (int K = K0; K >= 1 && m.harmonics.empty(); --K) {
                const int P = 2 * K + 1;
                Eigen::MatrixXd A(P, P);
                Eigen::VectorXd y(P);
                // column 0: 1; column 2j-1: cos j th; column 2j: sin j th
                A(0, 0) = C(0);
                y(0) = sum_e_;
                for (int j = 1; j <= K; ++j) {
                    A(0, 2 * j - 1) = A(2 * j - 1, 0) = C(j);
                    A(0, 2 * j) = A(2 * j, 0) = S(j);
                    y(2 * j - 1) = sum_ecos_[static_cast<std::size_t>(j)];
                    y(2 * j) = sum_esin_[static_cast<std::size_t>(j)];
                    for (int k = 1; k <= K; ++k) {
                        A(2 * j - 1, 2 * k - 1) = 0.5 * (C(j - k) + C(j + k));
                        A(2 * j, 2 * k) = 0.5 * (C(j - k) - C(j + k));
                        A(2 * j - 1, 2 * k) = 0.5 * (S(k + j) + S(k - j));  // cos j * sin k
                        A(2 * k, 2 * j - 1) = A(2 * j - 1, 2 * k);
                    }
                }
                Eigen::LDLT<Eigen::MatrixXd> ldlt(A);
                const Eigen::VectorXd d = ldlt.vectorD();
                if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || !(d.minCoeff() > 1e-9 * d.maxCoeff())) continue;
                const Eigen::VectorXd b = ldlt.solve(y);
                double power = 0;
                for (int k = 1; k <= K; ++k) {
                    const double a = b(2 * k - 1), c = b(2 * k);
                    m.harmonics.push_back({k, std::hypot(a, c), std::atan2(c, a)});
                    power += 0.5 * (a * a + c * c);
                }
                const double var = m2_ / static_cast<double>(m.scored);
                m.harmonic_power_fraction = var > 0 ? std::min(1.0, power / var) : 0.0;
                m.broadband_rms_rad = std::sqrt(std::max(0.0, var - power));
                if (K < o_.max_harmonic)
                    m.harmonics_note = "orders above " + std::to_string(K) + "x not fitted: " +
                                       (K == by_samples && K < covered / 4 ? std::to_string(m.scored) + " scored samples support no more (at most a quarter as many unknowns)"
                                                                           : "the scored samples visit too few distinct electrical angles (" + std::to_string(covered) + " of " +
                                                                                 std::to_string(kAngleBins) + " angle bins) to separate more");
            }
            if (m.harmonics.empty()) m.harmonics_note = "the scored samples visit too few distinct electrical angles to separate harmonics";
        }
        if (om_n_) {
            m.have_rate = true;
            m.omega_error_mean_rad_s = om_mean_;
            m.omega_error_std_rad_s = om_n_ > 1 ? std::sqrt(om_m2_ / static_cast<double>(om_n_ - 1)) : 0.0;
        }
        if (n_omega_true_) {
            const double mean_omega = sum_omega_true_ / static_cast<double>(n_omega_true_);
            if (std::fabs(mean_omega) > 1e-9) m.lag_s = -mean_ / mean_omega;
        }
    }
    if (locked_now_) m.lock_time_s = first_t_after_ - t0_;
    return m;
}

void ConventionCheck::add(std::size_t n, const double* th_true, const double* th_hat, const std::uint8_t* valid) {
    for (std::size_t i = 0; i < n; ++i) {
        if (!valid[i] || !std::isfinite(th_hat[i]) || !std::isfinite(th_true[i])) { have_ = false; continue; }
        if (have_) {
            const double dt = th_true[i] - last_true_, dh = th_hat[i] - last_hat_;
            ++pairs_;
            sum_abs_dtrue_ += std::fabs(dt);
            sum_abs_dhat_ += std::fabs(dh);
            if (std::fabs(std::fabs(dh - dt) - kTwoPi) < 0.5) ++wrap_jumps_;
        }
        have_ = true;
        last_true_ = th_true[i];
        last_hat_ = th_hat[i];
    }
}

std::vector<ConventionCheck::Finding> ConventionCheck::findings() const {
    std::vector<Finding> f;
    if (wrap_jumps_ > 0)
        f.push_back({"estimates_wrapped", "theta jumps by 2*pi between consecutive samples " + std::to_string(wrap_jumps_) +
                                              " times while the truth does not: the output looks wrapped; theta must be unwrapped (continuous across cycles)"});
    constexpr double kDeg = 180.0 / kPi;
    if (sum_abs_dtrue_ > 0.1 && pairs_ > 10) {
        const double ratio = sum_abs_dhat_ / sum_abs_dtrue_;
        if (std::fabs(ratio / kDeg - 1) < 0.1)
            f.push_back({"estimates_in_degrees", "theta changes " + std::to_string(ratio).substr(0, 5) +
                                                     " times as fast as the truth (180/pi = 57.3): the output looks like degrees; theta must be in radians"});
    }
    return f;
}

nlohmann::json angle_units(double rad, int lines) {
    nlohmann::json j{{"rad", rad}, {"percent_period", rad / kTwoPi * 100.0}};
    j["arcsec_mech"] = lines > 0 ? nlohmann::json(rad / lines * (180.0 / kPi) * 3600.0) : nlohmann::json();
    return j;
}

nlohmann::json to_json(const ErrorMetrics& m, int lines) {
    using nlohmann::json;
    // Statistics of nothing are not zero: without scored samples they are null.
    auto stat = [&](double v) { return m.scored ? angle_units(v, lines) : json(); };
    json j{{"samples", m.samples}, {"scored", m.scored}, {"invalid_after_settle", m.invalid_after_settle},
           {"removed_cycles", m.removed_cycles}, {"slipped_samples", m.scored ? json(m.slipped_samples) : json()},
           {"mean", stat(m.mean_rad)}, {"std", stat(m.std_rad)},
           {"rms", stat(m.rms_rad)}, {"max_abs", stat(m.max_abs_rad)},
           {"max_dev", stat(m.max_dev_rad)}};
    const auto vf = m.valid_fraction();
    j["evidence"] = {{"samples_after_settle", m.after_settle}, {"scored_samples", m.scored},
                     {"scored_cycles", m.cycles_scored}, {"valid_fraction", vf ? json(*vf) : json()}};
    auto h = json::array();
    for (const auto& x : m.harmonics)
        h.push_back({{"order", x.order}, {"amplitude", angle_units(x.amplitude_rad, lines)}, {"phase_rad", x.phase_rad}});
    j["harmonics"] = h;
    j["harmonic_analysis"] = {{"orders_requested", m.harmonics_requested},
                              {"orders_fitted", static_cast<int>(m.harmonics.size())},
                              {"power_fraction", m.harmonics.empty() ? json() : json(m.harmonic_power_fraction)},
                              {"broadband_rms_rad", m.harmonics.empty() ? json() : json(m.broadband_rms_rad)},
                              {"note", m.harmonics_note.empty() ? json() : json(m.harmonics_note)}};
    if (m.have_rate) j["omega_error"] = {{"mean_rad_s", m.omega_error_mean_rad_s}, {"std_rad_s", m.omega_error_std_rad_s}};
    if (m.omega_nonfinite) j["omega_nonfinite_samples"] = m.omega_nonfinite;
    j["lag_s"] = m.lag_s ? json(*m.lag_s) : json();
    j["lock_time_s"] = m.lock_time_s ? json(*m.lock_time_s) : json();
    return j;
}

}  // namespace fringe
