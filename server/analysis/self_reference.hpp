// Interpolation error without truth (docs/self-reference.md): each estimator's error measured
// against a reference phase built from the capture's own signals.
//
// The reference. The phase of the signals, u = unwrap(atan2(sin, cos)), is the true phase plus an
// error that repeats every electrical period (offsets, gains, quadrature, harmonics) plus noise.
// In each window of `window_cycles` periods (ended early by a gap or an invalid sample) it is
// fitted as
//
//   u(t_i) = s_w(t_i) + sum_{k=1..K} [a_k cos(k phi_i) + b_k sin(k phi_i)] + n_i
//
// with s_w a quintic in time (the motion, assumed smooth over the window) and phi the phase
// corrected by the window's own periodic part (one refinement), solved jointly so the smooth
// part cannot absorb the harmonics. s_w is the reference: it has no lag (the fit is symmetric in
// time) and averages the noise of the whole window.
//
// The error. For each sample e_i = theta_hat_i - s_w(t_i) (to the nearest whole turn), and over
// all windows e = c + sum_k [alpha_k cos(k s) + beta_k sin(k s)] + r: the harmonics of the
// estimator's error against the reference angle, and the rest (noise, varying lag). The error's
// rms about its mean is sqrt(sum (alpha_k^2 + beta_k^2) / 2 + var(r) + var(reference)): the
// signals' noise below a window's bandwidth is in the reference and in any tracking estimator
// alike, so it cancels in e and is added back from the reference fit's residual.
//
// What it cannot see: the error's mean (c includes the signals' own phase convention), motion
// that is not smooth over a window (the reference's residual shows it), and speed ripple locked
// to the electrical period. Memory is flat in the run's length (one window at a time).
#pragma once

#include <Eigen/Dense>
#include <nlohmann/json.hpp>

#include <cstddef>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace fringe {

struct SelfReferenceOptions {
    int harmonics = 8;                 // K: 1x..Kx fitted
    double window_cycles = 16;         // electrical periods a window spans before it closes
    double min_window_cycles = 4;      // a shorter window (ended by a gap, a stop or the end) is skipped
    std::size_t max_window_samples = 65536;
    double settle_s = 0;               // samples before t0 + settle_s are not used
};

struct SelfReferenceHarmonic {
    int order = 0;
    double amplitude_rad = 0;   // sqrt(alpha^2 + beta^2)
    double phase_rad = 0;       // alpha cos(k phi) + beta sin(k phi) = amplitude cos(k phi - phase)
    double u_rad = 0;           // standard uncertainty of alpha and of beta (correlated residual)
};

struct SelfReferenceResult {
    bool measured = false;
    std::string why_not;                 // when not measured
    std::uint64_t samples = 0;           // samples in the windows used
    std::uint64_t after_settle = 0;      // samples seen after the settle time
    std::uint64_t valid_after_settle = 0;  // of them, vouched for by the estimator with finite signals and output
    std::uint64_t windows = 0;           // windows used
    std::map<std::string, std::uint64_t> windows_skipped;  // reason -> count
    double cycles = 0;                   // electrical periods covered by the windows used
    double rms_rad = 0;                  // the error's rms about its mean
    double rms_u_rad = 0;                // its standard uncertainty
    double periodic_rms_rad = 0;         // the fitted harmonics' part
    double residual_rms_rad = 0;         // the rest (noise, varying lag), with the noise the reference shares
    double mean_vs_reference_rad = 0;    // c: not the error's mean (the signals' phase convention is in it)
    double correlation_samples = 1;      // the residual's correlation time (batch means)
    double reference_noise_rad = 0;      // rms of the reference's own error from the signals' noise
    double reference_residual_rms_rad = 0;  // what the reference fit leaves of the signals' phase
    double reference_correlation_samples = 1;  // its correlation time: >> 1 when the motion is not smooth over a window
    std::vector<SelfReferenceHarmonic> harmonics;
};

class SelfReference {
public:
    explicit SelfReference(SelfReferenceOptions o = {});
    // One block: the signals as delivered (V) and the estimator's output (unwrapped theta_hat,
    // rad; valid as it vouched).
    void add(std::size_t n, const double* t_s, const double* sin_v, const double* cos_v, const double* theta_hat_rad,
             const std::uint8_t* valid);
    SelfReferenceResult finish();

private:
    void close_window();

    SelfReferenceOptions o_;
    int p_;  // parameters of one window's reference fit: 6 (quintic) + 2K
    bool have_t0_ = false;
    double t0_ = 0;
    std::vector<double> t_, u_, y_;  // the open window: time, the signals' unwrapped phase, theta_hat
    double last_w_ = 0;              // the last wrapped phase (unwrapping)
    double lo_ = 0, hi_ = 0;         // u's range in the window
    // The error's regression over all windows: [1, cos k s, sin k s], k = 1..K.
    Eigen::MatrixXd n_;
    Eigen::VectorXd b_;
    double ee_ = 0;                  // sum of e^2 (e less the first window's mean)
    double e_ref_ = 0;
    bool have_e_ref_ = false;
    double ref_var_sum_ = 0;         // sum over samples of the reference's own variance
    SelfReferenceResult r_;
    // Batch means of each window's own residuals (error and reference), for correlation times.
    double batch_sq_ = 0, resid_sq_ = 0, ref_batch_sq_ = 0, ref_resid_sq_ = 0;
    std::uint64_t batches_ = 0;
};

nlohmann::json to_json(const SelfReferenceResult& r);

}  // namespace fringe
