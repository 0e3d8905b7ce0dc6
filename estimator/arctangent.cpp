// atan2 (nominal calibration) and atan2-ellipse (Heydemann correction), MODEL.md 4.1.
#include "common.hpp"
#include "correction.hpp"
#include "ellipse.hpp"
#include "registry_parts.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <memory>

namespace fringe::est {

namespace {

// Per tile of 1024 samples (its arrays stay in L1 from one pass to the next): normalise and
// atan2 (vectorised), then unwrap with an integer turn count, 128 samples at a time
// (Unwrapper::turns: only the running sum of the turn steps is serial, and only where the
// phase wraps). omega is the first difference of theta times fs (a memoryless estimator has
// no better rate estimate; it is noisy by nature); where the phase does not wrap, theta and
// omega come from the wrapped phase in one pass (theta[i - 1] recomputed as the same sum, so
// the same numbers).
// With a correction (docs/calibration.md), its periodic part is subtracted from each wrapped
// angle before unwrapping; without one the loop is the plain atan2's.
constexpr std::size_t kAtan2Tile = 1024;

void atan2_tile(const Calibration::Coeffs& cf, const double* __restrict s, const double* __restrict c,
                double* __restrict th, double* __restrict om, std::uint8_t* __restrict v, std::size_t n,
                Unwrapper& uw, double& prev_theta, bool& have_prev, double fs, std::uint8_t valid,
                const Correction* corr) {
    double w[kAtan2Tile];  // wrapped phase
    std::int64_t k[Unwrapper::kTurnsTile];
    // Constants in locals: the compiler cannot prove the calibration does not alias th.
    const auto [os, oc, inv_as, inv_ac, sin_d, inv_cos_d] = cf;
    for (std::size_t i = 0; i < n; ++i) {
        const double sn = (s[i] - os) * inv_as;
        const double cn = ((c[i] - oc) * inv_ac + sn * sin_d) * inv_cos_d;
        w[i] = fast_atan2(sn, cn);
    }
    if (corr) {
        const double off = corr->offset_rad;
        if (!corr->table.empty())
            for (std::size_t i = 0; i < n; ++i) w[i] -= off + corr->table_value(w[i]);
        else
            for (std::size_t i = 0; i < n; ++i) w[i] -= off + corr->harmonic_value(w[i]);
    }
    for (std::size_t off = 0; off < n; off += Unwrapper::kTurnsTile) {
        const std::size_t m = std::min(Unwrapper::kTurnsTile, n - off);
        const double* __restrict x = w + off;
        double* __restrict t = th + off;
        double* __restrict o = om + off;
        if (uw.turns(x, k, m)) {
            const double add = kTwoPi * static_cast<double>(k[0]);
            t[0] = x[0] + add;
            for (std::size_t i = 1; i < m; ++i) {
                const double ti = x[i] + add;
                t[i] = ti;
                o[i] = (ti - (x[i - 1] + add)) * fs;
            }
        } else {
            for (std::size_t i = 0; i < m; ++i) t[i] = x[i] + kTwoPi * static_cast<double>(k[i]);
            for (std::size_t i = 1; i < m; ++i) o[i] = (t[i] - t[i - 1]) * fs;
        }
        if (off > 0) o[0] = (t[0] - t[-1]) * fs;
    }
    om[0] = have_prev ? (th[0] - prev_theta) * fs : 0.0;
    for (std::size_t i = 0; i < n; ++i) v[i] = valid;
    prev_theta = th[n - 1];
    have_prev = true;
}

void atan2_block(const Calibration& cal, InputSpan in, OutputSpan out, Unwrapper& uw,
                 double& prev_theta, bool& have_prev, double fs, std::uint8_t valid,
                 const Correction* corr = nullptr) {
    constexpr std::size_t kTile = kAtan2Tile;
    const std::size_t n = in.size();
    const Calibration::Coeffs cf = cal.coeffs();
    for (std::size_t off = 0; off < n; off += kTile)
        atan2_tile(cf, in.sin_v.data() + off, in.cos_v.data() + off, out.theta_rad.data() + off,
                   out.omega_rad_s.data() + off, out.valid.data() + off, std::min(kTile, n - off), uw,
                   prev_theta, have_prev, fs, valid, corr);
}

class Atan2 final : public Estimator {
public:
    static std::vector<ParamInfo> params() {
        auto p = calibration_params();
        p.push_back(correction_param());
        return p;
    }
    void reset(const EstimatorConfig& cfg) override {
        const Params p = resolve_params(params(), cfg.params);
        if (!(cfg.sample_rate_hz > 0)) throw ConfigError("sample_rate_hz", "must be positive");
        fs_ = cfg.sample_rate_hz;
        cal_ = nominal_calibration(cfg.encoder, p);
        corr_ = correction_from_params(p, cal_);
        uw_.reset();
        have_prev_ = false;
    }
    void process(InputSpan in, OutputSpan out) override {
        atan2_block(cal_, in, out, uw_, prev_, have_prev_, fs_, 1, corr_.get());
    }
    BoundClass bound_class() const override { return BoundClass::Memoryless; }
    nlohmann::json state() const override {
        nlohmann::json j{{"calibration", cal_.to_json()}};
        if (corr_) j["correction"] = {{"table_entries", corr_->table.size()}, {"harmonics", corr_->cos_k.size()}};
        return j;
    }

private:
    double fs_ = 1;
    Calibration cal_;
    std::unique_ptr<Correction> corr_;
    Unwrapper uw_;
    double prev_ = 0;
    bool have_prev_ = false;
};

class Atan2Ellipse final : public Estimator {
public:
    static std::vector<ParamInfo> params() {
        auto p = calibration_params();
        for (auto& i : p) i.description = "initial calibration (until the first fit): " + i.description;
        p.push_back({"mode", "", ParamType::Choice, "batch", -kInf, kInf, {"batch", "recursive"},
                     "batch: one fit over the first calibration_samples (output invalid meanwhile); "
                     "recursive: refit continuously from phase-gated points with forgetting"});
        p.push_back({"calibration_samples", "samples", ParamType::Integer, 20000, 16, 1e9, {},
                     "batch window; should span at least one full electrical cycle"});
        p.push_back({"gate_rad", "rad", ParamType::Number, 0.1, 1e-4, 3.0, {},
                     "recursive: a point enters the fit only after the phase moved this far since the last one, so a standstill adds nothing and cannot drift the fit"});
        p.push_back({"memory_points", "points", ParamType::Number, 2000, 16, 1e9, {},
                     "recursive: forgetting horizon, in accepted points"});
        p.push_back({"refit_points", "points", ParamType::Integer, 64, 1, 1e9, {},
                     "recursive: refit after this many accepted points"});
        return p;
    }
    void reset(const EstimatorConfig& cfg) override {
        const Params p = resolve_params(params(), cfg.params);
        if (!(cfg.sample_rate_hz > 0)) throw ConfigError("sample_rate_hz", "must be positive");
        fs_ = cfg.sample_rate_hz;
        cal_ = nominal_calibration(cfg.encoder, p);
        recursive_ = p.string("mode") == "recursive";
        window_ = static_cast<std::uint64_t>(p.integer("calibration_samples"));
        gate_ = p.number("gate_rad");
        keep_ = 1.0 - 1.0 / p.number("memory_points");
        refit_ = static_cast<std::uint64_t>(p.integer("refit_points"));
        acc_ = {};
        seen_ = accepted_ = fits_ = 0;
        have_last_ = false;
        fitted_ = false;
        status_ = "not fitted yet";
        uw_.reset();
        have_prev_ = false;
    }
    void process(InputSpan in, OutputSpan out) override {
        if (recursive_) return process_recursive(in, out);
        // Batch: sub-blocks split at the end of the calibration window, so the fit takes
        // effect at the same sample whatever the caller's block size.
        std::size_t i = 0;
        const std::size_t n = in.size();
        while (i < n) {
            std::size_t m = n - i;
            if (!fitted_) m = std::min<std::uint64_t>(m, window_ - seen_);
            InputSpan si{in.sin_v.subspan(i, m), in.cos_v.subspan(i, m)};
            OutputSpan so{out.theta_rad.subspan(i, m), out.omega_rad_s.subspan(i, m), out.valid.subspan(i, m)};
            atan2_block(cal_, si, so, uw_, prev_, have_prev_, fs_, fitted_ ? 1 : 0);
            if (!fitted_) {
                for (std::size_t k = 0; k < m; ++k) acc_.add(si.sin_v[k], si.cos_v[k]);
                if (seen_ + m >= window_) {
                    refit();
                    fitted_ = true;  // one attempt; status_ says whether it worked
                }
            }
            seen_ += m;
            i += m;
        }
    }
    // Recursive: per sample, so each refit applies from the next sample on.
    void process_recursive(InputSpan in, OutputSpan out) {
        for (std::size_t k = 0; k < in.size(); ++k) {
            double sn, cn;
            cal_.normalise(in.sin_v[k], in.cos_v[k], sn, cn);
            const double a = uw_(fast_atan2(sn, cn));
            out.theta_rad[k] = a;
            out.omega_rad_s[k] = have_prev_ ? (a - prev_) * fs_ : 0.0;
            out.valid[k] = 1;
            prev_ = a;
            have_prev_ = true;
            if (!have_last_ || std::fabs(a - last_) >= gate_) {
                acc_.add(in.sin_v[k], in.cos_v[k], keep_);
                last_ = a;
                have_last_ = true;
                if (++accepted_ % refit_ == 0 && accepted_ >= 32) refit();
            }
        }
        seen_ += in.size();
    }
    BoundClass bound_class() const override { return BoundClass::Memoryless; }
    nlohmann::json state() const override {
        return {{"calibration", cal_.to_json()}, {"fit_status", status_}, {"fits", fits_},
                {"accepted_points", recursive_ ? accepted_ : seen_}};
    }

private:
    void refit() {
        Calibration c;
        const std::string why = fit_ellipse(acc_, c);
        if (why.empty()) {
            cal_ = c;
            ++fits_;
            status_ = "ok";
        } else {
            status_ = "fit rejected: " + why + " (calibration kept)";
        }
    }
    double fs_ = 1;
    Calibration cal_;
    bool recursive_ = false, fitted_ = false, have_last_ = false, have_prev_ = false;
    std::uint64_t window_ = 0, seen_ = 0, accepted_ = 0, refit_ = 64, fits_ = 0;
    double gate_ = 0.1, keep_ = 1.0, last_ = 0, prev_ = 0;
    ConicAccumulator acc_;
    Unwrapper uw_;
    std::string status_;
};

}  // namespace

std::string fit_ellipse(const ConicAccumulator& acc, Calibration& out) {
    if (acc.points < 6) return "too few points";
    Eigen::LDLT<Eigen::Matrix<double, 5, 5>> ldlt(acc.M);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return "normal equations not positive definite";
    const Eigen::Matrix<double, 5, 1> p = ldlt.solve(acc.v);
    // A singular fit (all points at one phase) shows as a tiny pivot.
    const auto d = ldlt.vectorD();
    if (!(d.minCoeff() > 1e-12 * d.maxCoeff())) return "degenerate (no motion over the calibration window?)";
    const double A = p(0), B = p(1), C = p(2), D = p(3), E = p(4);
    const double det = 4 * A * C - B * B;
    if (!(det > 0)) return "conic is not an ellipse";
    const double c0 = (-2 * C * D + B * E) / det, s0 = (B * D - 2 * A * E) / det;
    const double k = 1.0 + A * c0 * c0 + B * c0 * s0 + C * s0 * s0;
    if (!(k > 0)) return "ellipse does not enclose its centre";
    const double a1 = A / k, b1 = B / k, c1 = C / k;
    const double sd = b1 / (2 * std::sqrt(a1 * c1));
    if (!(std::fabs(sd) < 0.9)) return "quadrature error beyond 64 degrees";
    const double cd = std::sqrt(1 - sd * sd);
    Calibration cal;
    cal.offset_cos_v = c0;
    cal.offset_sin_v = s0;
    cal.amplitude_cos_v = 1.0 / (cd * std::sqrt(a1));
    cal.amplitude_sin_v = 1.0 / (cd * std::sqrt(c1));
    cal.quadrature_error_rad = std::asin(sd);
    cal.prepare();
    out = cal;
    return {};
}

void register_arctangent(std::vector<EstimatorInfo>& r) {
    r.push_back({"atan2", "Arctangent with the nominal calibration (offsets, amplitudes, quadrature from the profile or none); memoryless",
                 Atan2::params(), [] { return std::make_unique<Atan2>(); }});
    r.push_back({"atan2-ellipse",
                 "Arctangent after a Heydemann least-squares ellipse fit: batch over a calibration window, or recursive (phase-gated, forgetting; holds still at standstill)",
                 Atan2Ellipse::params(), [] { return std::make_unique<Atan2Ellipse>(); }});
}

}  // namespace fringe::est
