#include "server/analysis/self_reference.hpp"

#include "signal_gen/fastmath.hpp"

#include <algorithm>
#include <cmath>

namespace fringe {

namespace {
constexpr std::size_t kBatch = 256;  // batch length for the residuals' correlation times
constexpr int kPoly = 6;             // Legendre P0..P5 in time, per window

// tau = B var(batch means) / var: at least 1; 1 when there are too few batches to tell.
double correlation_time(double batch_sq, double resid_sq, std::uint64_t batches) {
    if (batches < 8 || !(resid_sq > 0)) return 1.0;
    return std::max(1.0, static_cast<double>(kBatch) * (batch_sq / static_cast<double>(batches)) /
                             (resid_sq / static_cast<double>(batches * kBatch)));
}
}  // namespace

SelfReference::SelfReference(SelfReferenceOptions o) : o_(o), p_(kPoly + 2 * o.harmonics) {
    n_ = Eigen::MatrixXd::Zero(1 + 2 * o_.harmonics, 1 + 2 * o_.harmonics);
    b_ = Eigen::VectorXd::Zero(1 + 2 * o_.harmonics);
}

void SelfReference::add(std::size_t n, const double* t_s, const double* sin_v, const double* cos_v, const double* theta_hat_rad,
                        const std::uint8_t* valid) {
    if (!n) return;
    if (!have_t0_) {
        t0_ = t_s[0];
        have_t0_ = true;
    }
    for (std::size_t i = 0; i < n; ++i) {
        const double th = theta_hat_rad[i];
        const bool settled = !(t_s[i] - t0_ < o_.settle_s);
        r_.after_settle += settled;
        if (!valid[i] || !std::isfinite(th) || !std::isfinite(t_s[i]) || !std::isfinite(sin_v[i]) || !std::isfinite(cos_v[i]) ||
            (sin_v[i] == 0 && cos_v[i] == 0) || !settled) {
            close_window();  // a gap ends the window: the motion model does not span it
            continue;
        }
        ++r_.valid_after_settle;
        const double w = std::atan2(sin_v[i], cos_v[i]);
        double u = w;
        if (!t_.empty()) {
            double d = w - last_w_;
            d -= kTwoPi * std::round(d / kTwoPi);
            u = u_.back() + d;
        }
        last_w_ = w;
        if (t_.empty()) lo_ = hi_ = u;
        lo_ = std::min(lo_, u);
        hi_ = std::max(hi_, u);
        t_.push_back(t_s[i]);
        u_.push_back(u);
        y_.push_back(th);
        // A window ends after window_cycles periods, and (once the rate is known) after twice the
        // time those took on average: near a stop or a reversal it stays short in time, so the
        // quintic still follows the motion, and is skipped when it swept too few periods.
        const double cap = r_.cycles > 0 ? 2.0 * o_.window_cycles * static_cast<double>(r_.samples) / r_.cycles
                                         : static_cast<double>(o_.max_window_samples);
        if (hi_ - lo_ >= kTwoPi * o_.window_cycles || t_.size() >= o_.max_window_samples || static_cast<double>(t_.size()) >= cap)
            close_window();
    }
}

void SelfReference::close_window() {
    const std::size_t n = t_.size();
    if (!n) return;
    const int k_max = o_.harmonics;
    const double cycles = (hi_ - lo_) / kTwoPi;
    auto clear = [&] {
        t_.clear();
        u_.clear();
        y_.clear();
    };
    auto skip = [&](const char* why) {
        ++r_.windows_skipped[why];
        clear();
    };
    if (cycles < o_.min_window_cycles) return skip("fewer electrical periods than min_window_cycles (a gap, a stop, a reversal or the end)");
    if (n < static_cast<std::size_t>(4 * p_)) return skip("too few samples for the window's parameters");
    if (static_cast<double>(n) / cycles < 2.0 * k_max + 2.0) return skip("fewer than 2K+2 samples per electrical period");
    const double t_mid = 0.5 * (t_.front() + t_.back()), half_s = 0.5 * (t_.back() - t_.front());
    if (!(half_s > 0)) return skip("no time span");
    const auto rows = static_cast<Eigen::Index>(n);

    // The reference fit of the signals' phase: a quintic in time (Legendre, well conditioned on
    // [-1, 1]) and the harmonics of the phase (cos/sin k phi by recurrence from k = 1).
    Eigen::MatrixXd a(rows, p_);
    Eigen::VectorXd u(rows);
    const double u0 = u_[0];
    auto harmonic_columns = [&](Eigen::MatrixXd& m, Eigen::Index row, Eigen::Index col0, double phi) {
        const double c1 = std::cos(phi), s1 = std::sin(phi);
        double c = c1, s = s1;
        for (int k = 0; k < k_max; ++k) {
            m(row, col0 + 2 * k) = c;
            m(row, col0 + 2 * k + 1) = s;
            const double cn = c * c1 - s * s1;
            s = s * c1 + c * s1;
            c = cn;
        }
    };
    for (Eigen::Index row = 0; row < rows; ++row) {
        const double x = (t_[static_cast<std::size_t>(row)] - t_mid) / half_s, x2 = x * x;
        a(row, 0) = 1.0;
        a(row, 1) = x;
        a(row, 2) = 0.5 * (3 * x2 - 1);
        a(row, 3) = 0.5 * x * (5 * x2 - 3);
        a(row, 4) = (35 * x2 * x2 - 30 * x2 + 3) / 8;
        a(row, 5) = x * (63 * x2 * x2 - 70 * x2 + 15) / 8;
        harmonic_columns(a, row, kPoly, u_[static_cast<std::size_t>(row)]);
        u(row) = u_[static_cast<std::size_t>(row)] - u0;
    }
    // The motion alone first, so what the joint fit sees is small (no cancellation in r'r).
    const auto poly = a.leftCols(kPoly);
    const Eigen::VectorXd coef = (poly.transpose() * poly).ldlt().solve(poly.transpose() * u);
    const Eigen::VectorXd ru = u - poly * coef;
    auto normal = [](const Eigen::MatrixXd& m) {
        Eigen::MatrixXd nm = Eigen::MatrixXd::Zero(m.cols(), m.cols());
        nm.selfadjointView<Eigen::Lower>().rankUpdate(m.transpose());
        return Eigen::MatrixXd(nm.selfadjointView<Eigen::Lower>());
    };
    // (The harmonic columns are taken at the measured phase: only the smooth part is kept, and
    // the harmonics are near orthogonal to it over whole periods, so the phase's own error does not
    // move it; the estimator's harmonics below are taken at the reference.)
    const Eigen::VectorXd x = normal(a).ldlt().solve(a.transpose() * ru);
    const Eigen::VectorXd eu = ru - a * x;  // what the reference fit leaves: noise, and motion it could not follow
    // The reference: the smooth part alone (no lag: the fit is symmetric in time).
    const Eigen::VectorXd s = (poly * (coef + x.head(kPoly))).array() + u0;
    double ref_batch = 0, ref_sq = eu.squaredNorm();
    std::uint64_t nb = 0;
    for (std::size_t s0 = 0; s0 + kBatch <= n; s0 += kBatch, ++nb) {
        const double mean = eu.segment(static_cast<Eigen::Index>(s0), kBatch).mean();
        ref_batch += mean * mean;
    }
    const double ref_batched_sq = eu.head(static_cast<Eigen::Index>(nb * kBatch)).squaredNorm();
    ref_batch_sq_ += ref_batch;
    ref_resid_sq_ += ref_batched_sq;
    // The reference's own error from the signals' noise: the quintic's share of the window,
    // about var(eu) tau kPoly / n a sample (tau: this window's correlation time).
    const double var_u = ref_sq / std::max(1.0, static_cast<double>(n) - p_);
    const double tau_u = correlation_time(ref_batch, ref_batched_sq, nb);
    ref_var_sum_ += var_u * tau_u * kPoly;

    // The estimator's error against the reference, to the nearest whole turn.
    Eigen::VectorXd e(rows);
    for (Eigen::Index row = 0; row < rows; ++row) e(row) = y_[static_cast<std::size_t>(row)] - s(row);
    // Whole turns relative to the first window's mean (an estimator whose phase origin differs
    // from the signals' by about pi must not flip a turn between windows).
    if (!have_e_ref_) {
        e.array() -= kTwoPi * std::round(e.mean() / kTwoPi);
        e_ref_ = e.mean();
        have_e_ref_ = true;
    } else {
        e.array() -= kTwoPi * std::round((e.mean() - e_ref_) / kTwoPi);
    }
    e.array() -= e_ref_;
    Eigen::MatrixXd g(rows, 1 + 2 * k_max);
    for (Eigen::Index row = 0; row < rows; ++row) {
        g(row, 0) = 1.0;
        harmonic_columns(g, row, 1, s(row));
    }
    const Eigen::MatrixXd gg = normal(g);
    const Eigen::VectorXd ge = g.transpose() * e;
    n_ += gg;
    b_ += ge;
    ee_ += e.squaredNorm();
    // The window's own fit of the error, for its residual's correlation time only.
    const Eigen::VectorXd er = e - g * gg.ldlt().solve(ge);
    for (std::size_t s0 = 0; s0 + kBatch <= n; s0 += kBatch) {
        const double mean = er.segment(static_cast<Eigen::Index>(s0), kBatch).mean();
        batch_sq_ += mean * mean;
        resid_sq_ += er.segment(static_cast<Eigen::Index>(s0), kBatch).squaredNorm();
        ++batches_;
    }
    r_.samples += n;
    r_.cycles += cycles;
    ++r_.windows;
    clear();
}

SelfReferenceResult SelfReference::finish() {
    close_window();
    SelfReferenceResult res = r_;
    const int k_max = o_.harmonics;
    const int pg = 1 + 2 * k_max;
    // With correlated residuals each fitted parameter takes about tau samples' worth of the
    // residual's variance, not one.
    const double tau = correlation_time(batch_sq_, resid_sq_, batches_);
    const double dof = static_cast<double>(res.samples) - tau * pg;
    if (!res.windows || dof <= 0) {
        if (res.after_settle > 0 && res.valid_after_settle == 0)  // the estimator's own verdict, not the motion's
            res.why_not = "the estimator marked all " + std::to_string(res.after_settle) +
                          " samples after the settle time invalid (its state says why; an estimator told another signal model or amplitude than "
                          "the capture's often does)";
        else if (res.windows)
            res.why_not = "too few samples in the windows used";
        else
            res.why_not = "no window of at least " + std::to_string(static_cast<int>(o_.min_window_cycles)) +
                          " electrical periods without a gap (the motion must sweep the phase several times, smoothly; an invalid estimate is a gap)";
        return res;
    }
    const auto nl = n_.ldlt();
    const Eigen::VectorXd h = nl.solve(b_);
    const double rss = std::max(0.0, ee_ - b_.dot(h));
    const double var = rss / dof;
    const double var_ref = ref_var_sum_ / static_cast<double>(res.samples);
    // The reference follows the signals' noise below the window's bandwidth, and so does any
    // estimator that tracks (its bandwidth is far above a window's): that share cancels in e and
    // is added back.
    const double var_rest = var + var_ref;
    res.correlation_samples = tau;
    res.reference_noise_rad = std::sqrt(var_ref);
    res.reference_residual_rms_rad = std::sqrt(ref_resid_sq_ / std::max(1.0, static_cast<double>(batches_ ? batches_ * kBatch : 1)));
    res.reference_correlation_samples = correlation_time(ref_batch_sq_, ref_resid_sq_, batches_);
    res.mean_vs_reference_rad = h(0) + e_ref_;
    const Eigen::MatrixXd cov = nl.solve(Eigen::MatrixXd::Identity(pg, pg)) * (var * tau);
    double periodic_sq = 0, var_periodic_sq = 0;
    for (int k = 0; k < k_max; ++k) {
        const double ak = h(1 + 2 * k), bk = h(2 + 2 * k);
        SelfReferenceHarmonic hk;
        hk.order = k + 1;
        hk.amplitude_rad = std::hypot(ak, bk);
        hk.phase_rad = std::atan2(bk, ak);
        hk.u_rad = std::sqrt(std::max(0.0, 0.5 * (cov(1 + 2 * k, 1 + 2 * k) + cov(2 + 2 * k, 2 + 2 * k))));
        // E|c|^2 = |c_true|^2 + 2 u^2: the noise's share removed from the rms.
        periodic_sq += std::max(0.0, hk.amplitude_rad * hk.amplitude_rad - 2 * hk.u_rad * hk.u_rad) / 2;
        var_periodic_sq += hk.amplitude_rad * hk.amplitude_rad * hk.u_rad * hk.u_rad;
        res.harmonics.push_back(hk);
    }
    res.periodic_rms_rad = std::sqrt(periodic_sq);
    res.residual_rms_rad = std::sqrt(var_rest);
    res.rms_rad = std::sqrt(periodic_sq + var_rest);
    const double nu = dof / tau;
    res.rms_u_rad = res.rms_rad > 0 ? std::sqrt(var_periodic_sq + 2 * var * var / nu + var_ref * var_ref) / (2 * res.rms_rad) : 0.0;
    res.measured = true;
    return res;
}

nlohmann::json to_json(const SelfReferenceResult& r) {
    using nlohmann::json;
    json skipped = json::object();
    for (const auto& [why, n] : r.windows_skipped) skipped[why] = n;
    json j{{"self_referenced", true},
           {"method", "against a reference phase from the signals themselves: per window of several electrical periods, the signals' phase "
                      "fitted as a quintic in time plus its harmonics; the quintic is the reference (docs/self-reference.md). The error's "
                      "mean is not observable"},
           {"measured", r.measured},
           {"samples", r.samples},
           {"samples_after_settle", r.after_settle},
           {"valid_fraction", r.after_settle ? json(static_cast<double>(r.valid_after_settle) / static_cast<double>(r.after_settle)) : json()},
           {"windows", r.windows},
           {"windows_skipped", skipped},
           {"cycles", r.cycles}};
    if (!r.measured) {
        j["why_not"] = r.why_not;
        return j;
    }
    json hs = json::array();
    for (const auto& h : r.harmonics)
        hs.push_back({{"order", h.order}, {"amplitude_rad", h.amplitude_rad}, {"phase_rad", h.phase_rad}, {"u_rad", h.u_rad}});
    j["rms_rad"] = r.rms_rad;
    j["rms_u_rad"] = r.rms_u_rad;
    j["periodic_rms_rad"] = r.periodic_rms_rad;
    j["residual_rms_rad"] = r.residual_rms_rad;
    j["mean_vs_reference_rad"] = r.mean_vs_reference_rad;
    j["correlation_samples"] = r.correlation_samples;
    j["harmonics"] = hs;
    j["reference"] = {{"noise_rad", r.reference_noise_rad},
                      {"residual_rms_rad", r.reference_residual_rms_rad},
                      {"correlation_samples", r.reference_correlation_samples}};
    return j;
}

}  // namespace fringe
