// The extended Kalman filter family of MODEL.md 4.3-4.4 (paper Figs 8-14).
//
// State: kinematics [theta_rad, omega_rad_s(, alpha_rad_s2)] followed by optional
// random-walk states: gain g (AGC), kappa (gap), offsets o_s/o_c (bias, V), gain mismatch
// eps and quadrature error delta_rad (self-calibration). The theta state is kept wrapped to
// (-pi, pi] with an integer turn count outside the filter, so precision does not degrade
// over long runs.
//
// Measurement models (channel voltages after the front end):
//   diffraction: h_ch = G_ch*(g*V_ch(theta; kappa, w, Vmax) - V_ref) + o_ch  (MODEL.md 2.2)
//   ideal sine:  h_s = g*A*(1+eps/2)*sin(theta) + o_s,
//                h_c = g*A*(1-eps/2)*cos(theta + delta) + o_c
// R = (sigma^2 + q_adc^2/12)*I + sigma_g^2*v*v', v the gain-scaled raw voltages.
#pragma once

#include "estimator.hpp"

#include <array>
#include <memory>

namespace fringe::est {

constexpr int kMaxStates = 9;

struct StateLayout {
    int n = 2;
    int alpha = -1, gain = -1, kappa = -1, off_s = -1, off_c = -1, eps = -1, delta = -1;
};

// Channel model: h(x), its Jacobian and the measurement noise at x.
class ChannelModel {
public:
    enum class Kind { Ideal, Diffraction };
    struct Setup {
        Kind kind = Kind::Diffraction;
        // diffraction
        double vmax_v = 1.0, aperture_w_rad = 2.8713, kappa = 1.0, reference_v = 0.0;
        // both: Lissajous errors known to the model
        double gain_sin = 1.0, gain_cos = 1.0, offset_sin_v = 0.0, offset_cos_v = 0.0, delta_rad = 0.0;
        // ideal: fundamental amplitude
        double amplitude_v = 1.0;
        double gain = 1.0;  // fixed gain when g is not a state
        double sigma_v = 1e-3, sigma_gain = 0.0, adc_step_v = 0.0;
        int harmonics = 1;  // diffraction: highest m modelled
    };
    void configure(const Setup& s, const StateLayout& L);
    // h[2], H[2][kMaxStates] (first L.n columns written), v[2] the gain-noise direction.
    void eval(const double* x, double h[2], double H[2][kMaxStates], double v[2]) const;
    // Measurement covariance for a given v and extra white variance (V^2).
    void noise(const double v[2], double extra_var_v2, double R[3]) const;  // R00, R01, R11
    // Mean Fisher information about theta per sample (MODEL.md 6) at the nominal state;
    // channels: 3 both, 1 sin only, 2 cos only.
    double mean_information(const double* x_nominal, int channels) const;
    const Setup& setup() const { return s_; }

private:
    Setup s_;
    StateLayout L_;
    std::array<double, 16> sinmw2_{}, p_s_{}, q_s_{}, p_c_{}, q_c_{};
    double white_var_ = 0, sin_delta_ = 0, cos_delta_ = 1;
};

// One EKF of any state size (dispatch to fixed-size Eigen code inside).
class Ekf {
public:
    struct Options {
        StateLayout layout;
        Kinematics kinematics = Kinematics::CV;
        double T_s = 1e-5;
        double q_kin = 0;  // PSD of white acceleration (CV, rad^2/s^3) or jerk (CA, rad^2/s^5)
        double q_gain_per_s = 0, q_kappa_per_s = 0, q_offset_v2_per_s = 0, q_eps_per_s = 0, q_delta_rad2_per_s = 0;
    };
    Ekf();
    ~Ekf();
    Ekf(Ekf&&) noexcept;
    Ekf& operator=(Ekf&&) noexcept;
    void configure(const Options& o, const ChannelModel* model);
    // x0 and the diagonal of P0.
    void init(const double* x0, const double* p0_diag);
    void predict();
    // Measurement update with channels 3 (both), 1 (sin), 2 (cos). fold: optional signed
    // permutation applied to (z - h), H and R (ekf-rectified). extra_var_v2 adds white
    // measurement variance (closed loop: its quantisation step). false if S is not PD.
    bool update(const double z[2], int channels, const double* fold2x2, double extra_var_v2);
    // Hold the states from index first on (the calibration states after the kinematic ones):
    // update() takes them as known constants, leaves their values and updates the other states
    // as a filter without them would. kMaxStates: none held.
    void hold_states_from(int first);
    // The covariance of the first count states back to p0_diag, uncorrelated with the others
    // (their values kept): what was learnt of them under an assumption that no longer holds.
    void reopen(int count, const double* p0_diag);
    // Model prediction at the current (a priori) state.
    void predict_measurement(double h[2]) const;
    double theta_rad() const;  // unwrapped
    double omega_rad_s() const;
    double state(int i) const;
    double cov(int i, int j) const;
    // Covariance check: symmetric to rounding and Cholesky-factorable.
    bool covariance_ok(double* min_eig = nullptr) const;

    struct Impl;

private:
    std::unique_ptr<Impl> impl_;
};

}  // namespace fringe::est
