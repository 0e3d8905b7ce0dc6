// Physical limits (MODEL.md 6): per-sample Cramer-Rao bound from the true signal model,
// the steady-state posterior CRB for a tracking prior (DARE), its measurement-noise-only
// part, and the batch bound of a deterministic linear phase. Variances in rad^2
// (electrical), rates in rad/s.
#pragma once

#include "drivers/device.hpp"
#include "estimator/estimator.hpp"
#include "signal_gen/encoder.hpp"

#include <nlohmann/json.hpp>

#include <Eigen/Dense>

#include <optional>

namespace fringe {

struct SignalInformation {
    double j_mean = 0, j_min = 0, j_max = 0;  // Fisher information about theta, 1/rad^2
    double r_rad2 = 0;                        // per-sample phase variance 1/J_bar
};

// J(theta) = h'(theta)' R^-1 h'(theta) over one electrical cycle at the nominal kappa, with
// h from the generator's own (noise-free) channel model, h' by central differences, and
// R = (sigma^2 + q_adc^2/12) I + sigma_g^2 v v'. nullopt if the profile has no noise at all
// (the bound is then zero and efficiency undefined). channels: 3 both, 1 sin only.
std::optional<SignalInformation> signal_information(const EncoderProfile& enc, int channels = 3);

struct TrackingBound {
    double pcrb_rad2 = 0;        // steady-state a posteriori P11 (DARE)
    double pcrb_omega_rad2_s2 = 0;
    double noise_only_rad2 = 0;  // part of P11 due to measurement noise (deterministic motion)
    double gain_theta = 0, gain_omega_per_s = 0;  // steady-state Kalman gains
    int iterations = 0;
};

// Steady-state bound for the CV (white acceleration, PSD q rad^2/s^3) or CA (white jerk)
// model with scalar phase measurements of variance r (MODEL.md 6: the PCRB recursion equals
// the Kalman Riccati recursion for y = theta + v). The Riccati recursion is iterated to a
// relative change below 1e-14; the noise-only part solves the Lyapunov equation
// P = A P A' + K r K', A = (I - K H) F, by doubling.
TrackingBound tracking_bound(est::Kinematics kin, double q, double r_rad2, double T_s);

// The same for any F, Q (first state observed with variance r).
TrackingBound steady_state_bound(const Eigen::MatrixXd& F, const Eigen::MatrixXd& Q, double r_rad2);

// Closed form for the discrete white-noise-acceleration model, Q = sigma_a^2*G*G' with
// G = [T^2/2, T] (Kalata; Bar-Shalom 6.5): an independent check of the Riccati solver.
TrackingBound kalata_cv(double sigma_a2, double r_rad2, double T_s);

// The encoder profile as the estimators receive the signal: the encoder's own noise and ADC
// plus the device's DAC and ADC quantisation (q^2/12 each) and analog noise, combined as white
// noise per channel. basis (optional) receives each contribution and what was assumed.
EncoderProfile delivered_profile(const EncoderProfile& enc, const dev::ConverterInfo& c, nlohmann::json* basis);

// Bounds for a scored run of an estimator: per-sample CRB, PCRB for its declared prior,
// batch bound over the scored samples, and the efficiency against the bound MODEL.md 6
// assigns to its class.
// An efficiency above this against the graded bound is not credible (bounds_json's
// "efficiency_not_credible"): the bound rests on a model the estimator does not follow.
inline constexpr double kMaxCredibleEfficiency = 1.2;

nlohmann::json bounds_json(const EncoderProfile& truth, const est::Estimator& e, double sample_rate_hz,
                           std::uint64_t scored_samples, double rms_rad, int channels = 3);

}  // namespace fringe
