#include "server/analysis/scoring.hpp"

#include "signal_gen/fastmath.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdio>

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
        batch0_sum_ += e;
        if (++batch0_n_ == kBatch0) { batch_done(batch0_sum_); batch0_sum_ = 0; batch0_n_ = 0; }
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
        for (std::size_t i = 0; i < ns; ++i) { sum_e_ += es[i]; sum_e2_ += es[i] * es[i]; }
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

// A completed batch of 64 samples (sum of e, rad): record its mean at level 0 and carry the sum
// up, where two batches make one of the next level.
void Scorer::batch_done(double sum) {
    double size = kBatch0;
    for (int l = 0; l < kBatchLevels; ++l, size *= 2) {
        BatchLevel& b = batches_[l];
        if (l > 0) {
            b.partial += sum;
            if (++b.parts < 2) return;
            sum = b.partial;
            b.partial = 0;
            b.parts = 0;
        }
        const double m = sum / size;
        b.s1 += m;
        b.s2 += m * m;
        ++b.n;
    }
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
                for (int k = 1; k <= K; ++k) {
                    const double a = b(2 * k - 1), c = b(2 * k);
                    m.harmonics.push_back({k, std::hypot(a, c), std::atan2(c, a)});
                }
                // What the fit leaves, from the same least squares: the residual sum of squares
                // is sum e^2 - b'y at the solution. Over a non-integer number of cycles the
                // harmonics are not orthogonal, so var - sum(a_k^2)/2 would be wrong (it was).
                const double rss = std::max(0.0, sum_e2_ - b.dot(y));
                m.harmonic_power_fraction = m2_ > 0 ? std::clamp(1.0 - rss / m2_, 0.0, 1.0) : 0.0;
                m.broadband_rms_rad = std::sqrt(rss / static_cast<double>(m.scored));
                if (K < o_.max_harmonic)
                    m.harmonics_note = "orders above " + std::to_string(K) + "x not fitted: " +
                                       (K == by_samples && K < covered / 4 ? std::to_string(m.scored) + " scored samples support no more (at most a quarter as many unknowns)"
                                                                           : "the scored samples visit too few distinct electrical angles (" + std::to_string(covered) + " of " +
                                                                                 std::to_string(kAngleBins) + " angle bins) to separate more");
            }
            if (m.harmonics.empty()) m.harmonics_note = "the scored samples visit too few distinct electrical angles to separate harmonics";
        }
        // Correlation time from batch means (the Bartlett estimate of the spectral density at 0).
        const double var = m2_ / static_cast<double>(m.scored);
        if (var > 0) {
            auto tau_at = [&](int l) {
                const BatchLevel& b = batches_[l];
                const double nb = static_cast<double>(b.n);
                const double vb = std::max(0.0, (b.s2 - b.s1 * b.s1 / nb) / (nb - 1));
                return static_cast<double>(kBatch0) * std::ldexp(1.0, l) * vb / var;
            };
            for (int l = kBatchLevels - 1; l >= 0; --l) {
                if (batches_[l].n < 32) continue;
                m.correlation_samples = std::clamp(tau_at(l), 1.0, static_cast<double>(m.scored));
                m.correlation_batch = static_cast<std::uint64_t>(kBatch0) << l;
                break;
            }
            // A short run (no level with 32 batches): batches too short to see a tracker's
            // correlation, so the largest tau of any level with at least 4 batches (conservative;
            // the interval is marked approximate).
            if (!m.correlation_samples) {
                for (int l = 0; l < kBatchLevels && batches_[l].n >= 4; ++l) {
                    const double t = tau_at(l);
                    if (!m.correlation_samples || t > *m.correlation_samples) {
                        m.correlation_samples = t;
                        m.correlation_batch = static_cast<std::uint64_t>(kBatch0) << l;
                    }
                }
                if (m.correlation_samples) {
                    m.correlation_samples = std::clamp(*m.correlation_samples, 1.0, static_cast<double>(m.scored));
                    m.correlation_approximate = true;
                }
            }
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
    constexpr double kHalfTurnDeg = 180.0;
    for (std::size_t i = 0; i < n; ++i) {
        if (!valid[i] || !std::isfinite(th_hat[i]) || !std::isfinite(th_true[i])) { have_ = false; continue; }
        min_hat_ = std::min(min_hat_, th_hat[i]);
        max_hat_ = std::max(max_hat_, th_hat[i]);
        if (have_) {
            const double dt = th_true[i] - last_true_, dh = th_hat[i] - last_hat_;
            ++pairs_;
            sum_abs_dtrue_ += std::fabs(dt);
            sum_abs_dhat_ += std::fabs(dh);
            if (std::fabs(std::fabs(dh - dt) - kTwoPi) < 0.5) ++wrap_jumps_;
            if (std::fabs(dh) > kHalfTurnDeg) {
                ++deg_jumps_;
            } else {
                ++deg_pairs_;
                deg_sum_abs_dtrue_ += std::fabs(dt);
                deg_sum_abs_dhat_ += std::fabs(dh);
            }
        }
        have_ = true;
        last_true_ = th_true[i];
        last_hat_ = th_hat[i];
    }
}

std::vector<ConventionCheck::Finding> ConventionCheck::findings() const {
    std::vector<Finding> f;
    constexpr double kDeg = 180.0 / kPi;
    auto fmt = [](double v) {
        char b[32];
        std::snprintf(b, sizeof b, "%.4g", v);
        return std::string(b);
    };
    // Degrees first: wrapped degrees also jump, by 360, and the 2*pi test must not name them radians.
    if (deg_sum_abs_dtrue_ > 0.1 && deg_pairs_ > 10) {
        const double ratio = deg_sum_abs_dhat_ / deg_sum_abs_dtrue_;
        if (std::fabs(ratio / kDeg - 1) < 0.1) {
            std::string how = "theta changes " + fmt(ratio) + " times as fast as the truth (180/pi = 57.3): the output looks like degrees";
            if (deg_jumps_ > 0) {
                const char* range = min_hat_ >= -1e-9 && max_hat_ <= 360.0 + 1e-9 ? ", wrapped to [0, 360)"
                                    : min_hat_ >= -180.0 - 1e-9 && max_hat_ <= 180.0 + 1e-9 ? ", wrapped to (-180, 180]"
                                                                                                : ", wrapped";
                how += std::string(range) + " (" + std::to_string(deg_jumps_) + " jumps of 360 between consecutive samples)";
                f.push_back({"estimates_in_degrees_wrapped", how + "; theta must be unwrapped radians"});
            } else {
                f.push_back({"estimates_in_degrees", how + "; theta must be in radians"});
            }
            return f;
        }
    }
    if (wrap_jumps_ > 0)
        f.push_back({"estimates_wrapped", "theta jumps by 2*pi between consecutive samples " + std::to_string(wrap_jumps_) +
                                              " times while the truth does not: the output looks wrapped; theta must be unwrapped (continuous across cycles)"});
    else if (sum_abs_dtrue_ > 0.1 && pairs_ > 10) {
        const double ratio = sum_abs_dhat_ / sum_abs_dtrue_;
        if (std::fabs(ratio / kDeg - 1) < 0.1)
            f.push_back({"estimates_in_degrees", "theta changes " + fmt(ratio) + " times as fast as the truth (180/pi = 57.3): the output looks like degrees; theta must be in radians"});
    }
    return f;
}

nlohmann::json angle_units(double rad, int lines) {
    nlohmann::json j{{"rad", rad}, {"percent_period", rad / kTwoPi * 100.0}};
    j["arcsec_mech"] = lines > 0 ? nlohmann::json(rad / lines * (180.0 / kPi) * 3600.0) : nlohmann::json();
    return j;
}

namespace {

constexpr double kZ95 = 1.959963984540054;  // two-sided 95 % normal quantile

// Chi-square quantile with nu degrees of freedom at normal quantile z (Wilson-Hilferty; within
// 1 % of the exact value for nu >= 3).
double chi2_quantile(double nu, double z) {
    const double a = 2.0 / (9.0 * nu);
    const double c = 1.0 - a + z * std::sqrt(a);
    return nu * c * c * c;
}

}  // namespace

nlohmann::json uncertainty_json(const ErrorMetrics& m) {
    using nlohmann::json;
    json u{{"confidence", 0.95},
           {"method", "the error's correlation time tau = S(0)/variance from batch means (docs/model.md#uncertainty); "
                      "independent samples = scored / tau; std and broadband rms by chi-square, mean and harmonics by the normal law, rms by the delta method"}};
    if (!m.scored || !m.correlation_samples) {
        u["note"] = m.scored ? "too few scored samples to estimate the error's correlation time (at least 4 batches of 64)" : "nothing scored";
        return u;
    }
    const double tau = *m.correlation_samples, nu = static_cast<double>(m.scored) / tau;
    u["correlation_samples"] = tau;
    u["correlation_batch_samples"] = m.correlation_batch;
    u["independent_samples"] = nu;
    if (m.correlation_approximate)
        u["note"] = "approximate: fewer than 2048 scored samples, too few to resolve the error's correlation time; tau is the largest of the batch lengths tried (a longer run narrows and firms the interval)";
    if (nu < 3) {
        u["note"] = "fewer than 3 independent samples: no interval";
        return u;
    }
    const double sigma = m.std_rad, mu = m.mean_rad;
    auto pair = [](double lo, double hi) { return json::array({lo, hi}); };
    const double chi_hi = chi2_quantile(nu, kZ95), chi_lo = chi2_quantile(nu, -kZ95);
    auto spread = [&](double s) { return pair(s * std::sqrt(nu / chi_hi), s * std::sqrt(nu / std::max(chi_lo, 1e-300))); };
    u["mean_rad"] = pair(mu - kZ95 * sigma / std::sqrt(nu), mu + kZ95 * sigma / std::sqrt(nu));
    u["std_rad"] = spread(sigma);
    // rms^2 = mu^2 + sigma^2; var(rms^2) ~ (2 sigma^4 + 4 mu^2 sigma^2) / nu
    const double r2 = m.rms_rad * m.rms_rad, sd_r2 = std::sqrt((2 * sigma * sigma * sigma * sigma + 4 * mu * mu * sigma * sigma) / nu);
    u["rms_rad"] = pair(std::sqrt(std::max(0.0, r2 - kZ95 * sd_r2)), std::sqrt(r2 + kZ95 * sd_r2));
    if (!m.harmonics.empty()) {
        u["broadband_rms_rad"] = spread(m.broadband_rms_rad);
        // a least-squares cos/sin coefficient over nu independent samples of the residual: sd sigma_b sqrt(2/nu)
        const double sd_a = m.broadband_rms_rad * std::sqrt(2.0 / nu);
        json h = json::array();
        for (const auto& x : m.harmonics)
            h.push_back({{"order", x.order}, {"amplitude_rad", pair(std::max(0.0, x.amplitude_rad - kZ95 * sd_a), x.amplitude_rad + kZ95 * sd_a)}});
        u["harmonics"] = h;
    }
    return u;
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
    j["uncertainty"] = uncertainty_json(m);
    return j;
}

}  // namespace fringe
