// Scoring estimates against truth (MODEL.md 7), streamed in blocks so runs of 10^8 samples
// need bounded memory.
//
// e = theta_hat - theta_true over valid samples after the settle time, minus the whole
// multiple of 2*pi nearest the median of the first kMedianWindow scored errors (a cycle slip
// later in the run stays visible as slipped samples). All angles are electrical radians.
#pragma once

#include <nlohmann/json.hpp>

#include <Eigen/Dense>

#include <cstdint>
#include <optional>
#include <vector>

namespace fringe {

struct HarmonicAmplitude {
    int order = 0;           // k: multiple of the electrical phase
    double amplitude_rad = 0;
    double phase_rad = 0;    // e_k(theta) = amplitude*cos(k*theta - phase)
};

struct ErrorMetrics {
    std::uint64_t samples = 0;          // all samples seen
    std::uint64_t scored = 0;           // valid and after the settle time
    std::uint64_t invalid_after_settle = 0;
    double removed_cycles = 0;          // multiple of 2*pi removed
    double mean_rad = 0, std_rad = 0, rms_rad = 0, max_abs_rad = 0, max_dev_rad = 0;
    std::uint64_t slipped_samples = 0;  // |e| > pi after the multiple is removed
    std::vector<HarmonicAmplitude> harmonics;  // 1x..6x
    bool have_rate = false;
    double omega_error_mean_rad_s = 0, omega_error_std_rad_s = 0;
    std::optional<double> lag_s;        // mean phase error / mean true rate (moving runs only)
    std::optional<double> lock_time_s;  // after the last sample with |wrap(e)| > lock threshold or invalid
};

class Scorer {
public:
    static constexpr std::size_t kMedianWindow = 65536;
    static constexpr int kHarmonics = 6;
    Scorer(double settle_s, double lock_threshold_rad = 0.1);
    // omega_true / omega_hat may be null.
    void add(std::size_t n, const double* t_s, const double* theta_true, const double* omega_true,
             const double* theta_hat, const double* omega_hat, const std::uint8_t* valid);
    ErrorMetrics finish();

private:
    void accumulate(double e, double theta_true);
    void flush_harmonics();
    double settle_s_, lock_thr_;
    bool decided_ = false;
    double offset_rad_ = 0;
    std::vector<double> pending_e_, pending_th_;
    ErrorMetrics m_;
    double t0_ = 0;
    bool have_t0_ = false;
    double last_unlocked_t_ = -1e300, first_t_after_ = 0;
    bool locked_now_ = false, ever_ = false;
    // Welford
    double mean_ = 0, m2_ = 0, min_e_ = 1e300, max_e_ = -1e300;
    double om_mean_ = 0, om_m2_ = 0;
    std::uint64_t om_n_ = 0;
    double sum_omega_true_ = 0;
    // harmonic least squares: rows [1, cos k th, sin k th], normal equations
    Eigen::Matrix<double, Eigen::Dynamic, 2 * kHarmonics + 1> X_;
    Eigen::VectorXd y_;
    std::size_t rows_ = 0;
    Eigen::Matrix<double, 2 * kHarmonics + 1, 2 * kHarmonics + 1> XtX_;
    Eigen::Matrix<double, 2 * kHarmonics + 1, 1> Xty_;
};

// Angles in the report's three units (DESIGN.md): electrical rad, % of a signal period,
// mechanical arcsec.
nlohmann::json angle_units(double rad, int lines_per_rev);
nlohmann::json to_json(const ErrorMetrics& m, int lines_per_rev);

}  // namespace fringe
