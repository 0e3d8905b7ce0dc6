// Every registered estimator (except external) in the option combinations the divergence
// tests run: told nothing where the estimator can start without a profile, told the
// generator's profile where it needs one (a diffraction model).
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace fringe::test {

struct EstimatorConfigCase {
    std::string name;
    nlohmann::json params;
    bool told = false;  // given the true encoder profile
};

inline std::vector<EstimatorConfigCase> divergence_configs() {
    using nlohmann::json;
    std::vector<EstimatorConfigCase> c = {
        {"atan2", json::object(), false},
        {"atan2-ellipse", {{"calibration_samples", 5000}}, false},
        {"atan2-ellipse", {{"mode", "recursive"}}, false},
        {"pll2", json::object(), false},
        {"pll2", {{"natural_freq_hz", 20.0}}, false},
        {"ekf-selfcal", json::object(), false},
        {"ekf-selfcal", {{"kinematics", "ca"}}, false},
        {"ekf-rectified", {{"model", "ideal"}}, false},
        {"ekf-sin-only", {{"model", "ideal"}}, false},
        {"ekf-parallel", {{"model", "ideal"}}, false},
        {"ekf-diffraction", json::object(), true},
        {"ekf-sin-only", json::object(), true},
        {"ekf-parallel", json::object(), true},
        {"ekf-rectified", json::object(), true},
        {"closed-loop", json::object(), true},
        {"ekf-auto", json::object(), false},
    };
    // every option combination of the two-channel EKFs
    for (const char* kin : {"cv", "ca"})
        for (int agc = 0; agc < 2; ++agc)
            for (int off = 0; off < 2; ++off) {
                c.push_back({"ekf-ideal", {{"kinematics", kin}, {"agc", agc == 1}, {"track_offsets", off == 1}}, false});
                for (int kap = 0; kap < 2; ++kap)
                    c.push_back({"ekf-diffraction", {{"kinematics", kin}, {"agc", agc == 1}, {"track_offsets", off == 1}, {"track_kappa", kap == 1}}, true});
            }
    return c;
}

}  // namespace fringe::test
