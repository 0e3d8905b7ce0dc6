#include "ekf.hpp"
#include "ekf_impl.hpp"

#include "common.hpp"

#include "signal_gen/fastmath.hpp"
#include "signal_gen/optics.hpp"

#include <Eigen/Dense>

#include <cmath>

namespace fringe::est {

// ---------------------------------------------------------------- channel model

void ChannelModel::configure(const Setup& s, const StateLayout& L) {
    s_ = s;
    L_ = L;
    if (s_.kind == Kind::Diffraction) {
        if (s_.harmonics < 1 || s_.harmonics > 15) throw ConfigError("params.kappa", "harmonic count out of range");
        for (int m = 1; m <= s_.harmonics; ++m) {
            sinmw2_[m] = std::sin(m * s_.aperture_w_rad / 2);
            // sin channel centred at theta - pi/2, cos at theta + delta (MODEL.md 2.2, 2.5)
            p_s_[m] = std::cos(m * kPi / 2);
            q_s_[m] = std::sin(m * kPi / 2);
            p_c_[m] = std::cos(m * s_.delta_rad);
            q_c_[m] = -std::sin(m * s_.delta_rad);
        }
    }
    sin_delta_ = std::sin(s_.delta_rad);
    cos_delta_ = std::cos(s_.delta_rad);
    white_var_ = s_.sigma_v * s_.sigma_v + s_.adc_step_v * s_.adc_step_v / 12.0;
}

double ChannelModel::mean_information(const double* x_nominal, int channels) const {
    constexpr int kGrid = 720;
    double x[kMaxStates];
    for (int i = 0; i < L_.n; ++i) x[i] = x_nominal[i];
    double sum = 0;
    for (int k = 0; k < kGrid; ++k) {
        x[0] = -kPi + kTwoPi * (k + 0.5) / kGrid;
        double h[2], H[2][kMaxStates], v[2], R[3];
        eval(x, h, H, v);
        noise(v, 0.0, R);
        if (channels == 1) sum += H[0][0] * H[0][0] / R[0];
        else if (channels == 2) sum += H[1][0] * H[1][0] / R[2];
        else {
            Eigen::Matrix2d Rm;
            Rm << R[0], R[1], R[1], R[2];
            Eigen::Vector2d d(H[0][0], H[1][0]);
            Eigen::LDLT<Eigen::Matrix2d> ldlt(Rm);
            if (ldlt.info() != Eigen::Success || !ldlt.isPositive())
                throw ConfigError("params.sigma_v", "measurement covariance is not positive definite");
            sum += d.dot(ldlt.solve(d));
        }
    }
    return sum / kGrid;
}

// ---------------------------------------------------------------- filter (ekf_impl.hpp)

namespace ekf_detail {

bool dynamic_covariance_ok(const Eigen::MatrixXd& P, double* min_eig) {
    const double asym = (P - P.transpose()).cwiseAbs().maxCoeff();
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(P, Eigen::EigenvaluesOnly);
    if (min_eig) *min_eig = es.eigenvalues().minCoeff();
    Eigen::LLT<Eigen::MatrixXd> llt(P);
    return asym <= 1e-12 * P.cwiseAbs().maxCoeff() && llt.info() == Eigen::Success && es.eigenvalues().minCoeff() > 0;
}

}  // namespace ekf_detail

namespace {

std::unique_ptr<Ekf::Impl> make_impl(const Ekf::Options& o, const ChannelModel* m) {
    switch (o.layout.n) {
        case 2: case 3: case 4: return ekf_detail::make_states_2_4(o, m);
        case 5: case 6: return ekf_detail::make_states_5_6(o, m);
        case 7: return ekf_detail::make_states_7(o, m);
        case 8: case 9: return ekf_detail::make_states_dynamic(o, m);
    }
    throw ConfigError("params", "unsupported EKF state size " + std::to_string(o.layout.n));
}

}  // namespace

Ekf::Ekf() = default;
Ekf::~Ekf() = default;
Ekf::Ekf(Ekf&&) noexcept = default;
Ekf& Ekf::operator=(Ekf&&) noexcept = default;

void Ekf::configure(const Options& o, const ChannelModel* model) { impl_ = make_impl(o, model); }
void Ekf::init(const double* x0, const double* p0) { impl_->init(x0, p0); }
void Ekf::predict() { impl_->predict(); }
bool Ekf::update(const double z[2], int channels, const double* fold, double extra) {
    return impl_->update(z, channels, fold, extra);
}
void Ekf::hold_states_from(int first) { impl_->hold_from = first; }
void Ekf::reopen(int count, const double* p0_diag) { impl_->reopen(count, p0_diag); }
void Ekf::predict_measurement(double h[2]) const { impl_->predict_measurement(h); }
double Ekf::theta_rad() const { return impl_->x(0) + kTwoPi * static_cast<double>(impl_->turns); }
double Ekf::omega_rad_s() const { return impl_->x(1); }
double Ekf::state(int i) const { return impl_->x(i); }
double Ekf::cov(int i, int j) const { return impl_->P(i, j); }
bool Ekf::covariance_ok(double* min_eig) const { return impl_->covariance_ok(min_eig); }

}  // namespace fringe::est
