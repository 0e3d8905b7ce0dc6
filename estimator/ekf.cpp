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

void ChannelModel::eval(const double* x, double h[2], double H[2][kMaxStates], double v[2]) const {
    for (int i = 0; i < L_.n; ++i) H[0][i] = H[1][i] = 0.0;
    const double theta = x[0];
    const double g = L_.gain >= 0 ? x[L_.gain] : s_.gain;
    const double os = L_.off_s >= 0 ? x[L_.off_s] : s_.offset_sin_v;
    const double oc = L_.off_c >= 0 ? x[L_.off_c] : s_.offset_cos_v;
    double s1, c1;
    sincos_small(theta, s1, c1);  // theta is the wrapped state, |theta| <= pi + one step
    if (s_.kind == Kind::Diffraction) {
        const double kappa = L_.kappa >= 0 ? x[L_.kappa] : s_.kappa;
        const double inv2k = 0.5 / kappa, invk2 = 1.0 / (kappa * kappa);
        double vs = s_.aperture_w_rad / 2, vc = vs, ds = 0, dc = 0, ks = 0, kc = 0;
        double cm = c1, sm = s1;
        for (int m = 1; m <= s_.harmonics; ++m) {
            const double wgt = 1.0 - m * inv2k;
            if (wgt > 0) {
                const double B = (2.0 / m) * wgt * sinmw2_[m];
                const double dB = sinmw2_[m] * invk2;
                const double fs = p_s_[m] * cm + q_s_[m] * sm, fc = p_c_[m] * cm + q_c_[m] * sm;
                vs += B * fs;
                vc += B * fc;
                ds += B * m * (q_s_[m] * cm - p_s_[m] * sm);
                dc += B * m * (q_c_[m] * cm - p_c_[m] * sm);
                if (L_.kappa >= 0) {
                    ks += dB * fs;
                    kc += dB * fc;
                }
            }
            const double cn = cm * c1 - sm * s1;
            sm = sm * c1 + cm * s1;
            cm = cn;
        }
        const double V = s_.vmax_v;
        const double gs = s_.gain_sin, gc = s_.gain_cos;
        h[0] = gs * (g * V * vs - s_.reference_v) + os;
        h[1] = gc * (g * V * vc - s_.reference_v) + oc;
        v[0] = gs * g * V * vs;
        v[1] = gc * g * V * vc;
        H[0][0] = gs * g * V * ds;
        H[1][0] = gc * g * V * dc;
        if (L_.gain >= 0) { H[0][L_.gain] = gs * V * vs; H[1][L_.gain] = gc * V * vc; }
        if (L_.kappa >= 0) { H[0][L_.kappa] = gs * g * V * ks; H[1][L_.kappa] = gc * g * V * kc; }
    } else {
        const double eps = L_.eps >= 0 ? x[L_.eps] : 0.0;
        double sd = sin_delta_, cd = cos_delta_;
        if (L_.delta >= 0) sincos_small(x[L_.delta], sd, cd);
        const double sin_td = s1 * cd + c1 * sd, cos_td = c1 * cd - s1 * sd;  // theta + delta
        const double A = s_.amplitude_v;
        const double As = A * (s_.gain_sin + eps / 2), Ac = A * (s_.gain_cos - eps / 2);
        h[0] = g * As * s1 + os;
        h[1] = g * Ac * cos_td + oc;
        v[0] = g * As * s1;
        v[1] = g * Ac * cos_td;
        H[0][0] = g * As * c1;
        H[1][0] = -g * Ac * sin_td;
        if (L_.gain >= 0) { H[0][L_.gain] = As * s1; H[1][L_.gain] = Ac * cos_td; }
        if (L_.eps >= 0) { H[0][L_.eps] = g * A * s1 / 2; H[1][L_.eps] = -g * A * cos_td / 2; }
        if (L_.delta >= 0) H[1][L_.delta] = -g * Ac * sin_td;
    }
    if (L_.off_s >= 0) H[0][L_.off_s] = 1.0;
    if (L_.off_c >= 0) H[1][L_.off_c] = 1.0;
}

void ChannelModel::noise(const double v[2], double extra_var_v2, double R[3]) const {
    const double sg2 = s_.sigma_gain * s_.sigma_gain;
    const double w = white_var_ + extra_var_v2;
    R[0] = w + sg2 * v[0] * v[0];
    R[1] = sg2 * v[0] * v[1];
    R[2] = w + sg2 * v[1] * v[1];
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
void Ekf::predict_measurement(double h[2]) const { impl_->predict_measurement(h); }
double Ekf::theta_rad() const { return impl_->x(0) + kTwoPi * static_cast<double>(impl_->turns); }
double Ekf::omega_rad_s() const { return impl_->x(1); }
double Ekf::state(int i) const { return impl_->x(i); }
double Ekf::cov(int i, int j) const { return impl_->P(i, j); }
bool Ekf::covariance_ok(double* min_eig) const { return impl_->covariance_ok(min_eig); }

}  // namespace fringe::est
