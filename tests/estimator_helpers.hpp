#pragma once

#include "helpers.hpp"

#include "estimator/estimator.hpp"
#include "server/analysis/bounds.hpp"
#include "server/analysis/scoring.hpp"

#include <memory>
#include <optional>
#include <string>

namespace fringe::test {

struct EstimateRun {
    std::unique_ptr<est::Estimator> e;
    std::vector<double> theta, omega;
    std::vector<std::uint8_t> valid;
    ErrorMetrics m;
    nlohmann::json bounds;
    double efficiency() const { return bounds.value("efficiency", nlohmann::json()).is_null() ? -1.0 : bounds["efficiency"].get<double>(); }
};

// Run an estimator over a generated block in one call, score it after settle_s and compute
// its bounds from the truth profile.
inline EstimateRun run_estimator(const std::string& name, const nlohmann::json& params,
                                 const std::optional<EncoderProfile>& told, const Block& b, double fs,
                                 const EncoderProfile& truth, double settle_s = 0.1) {
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = fs;
    cfg.encoder = told;
    cfg.params = params;
    EstimateRun r;
    r.e = est::make(name, cfg);
    const std::size_t n = b.size();
    r.theta.resize(n); r.omega.resize(n); r.valid.resize(n);
    r.e->process({b.sin_v, b.cos_v}, {r.theta, r.omega, r.valid});
    Scorer s(settle_s);
    s.add(n, b.t_s.data(), b.theta_rad.data(), b.omega_rad_s.data(), r.theta.data(), r.omega.data(), r.valid.data());
    r.m = s.finish();
    r.bounds = bounds_json(truth, *r.e, fs, r.m.scored, r.m.rms_rad);
    return r;
}

inline double harmonic(const ErrorMetrics& m, int k) {
    for (const auto& h : m.harmonics)
        if (h.order == k) return h.amplitude_rad;
    return -1;
}

}  // namespace fringe::test
