// Shaft motion profiles: phi(t) (rad), omega(t) (rad/s), alpha(t) (rad/s^2), in closed form
// so that truth is exact at every sample.
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <cstddef>
#include <string>
#include <vector>

namespace fringe {

enum class MotionKind { Constant, Ramp, Trapezoid, Sine, Steps, Table };

struct MotionProfile {
    MotionKind kind = MotionKind::Constant;
    double phi0_rad = 0.0;
    double velocity_rad_s = 0.0;   // constant; ramp: initial; trapezoid: cruise; sine: drift
    double accel_rad_s2 = 0.0;     // ramp, trapezoid
    double start_s = 0.0;          // trapezoid: time at rest before the move
    double cruise_s = 0.0;         // trapezoid: time at cruise speed
    double amplitude_rad = 0.0;    // sine: phi0 + amp*sin(2*pi*f*t + phase) + v*t
    double freq_hz = 0.0;
    double phase_rad = 0.0;
    double step_rad = 0.0;         // steps: phi0 + step*floor(t/dwell)
    double dwell_s = 1.0;
    std::vector<double> table_t_s, table_phi_rad;  // table: piecewise linear phi(t)
    std::string table_file;

    // Fill phi/omega/alpha for n sample times t_s[i].
    void evaluate(const double* t_s, std::size_t n, double* phi_rad, double* omega_rad_s,
                  double* alpha_rad_s2) const;
    std::string kind_name() const;
};

// base_dir resolves a table's relative "file". electrical_freq_hz (constant motion) needs
// lines_per_rev to become a shaft velocity.
MotionProfile motion_from_json(const nlohmann::json& j, const std::string& base_dir,
                               int lines_per_rev, const std::string& path = "motion");
void to_json(nlohmann::json& j, const MotionProfile& m);

}  // namespace fringe
