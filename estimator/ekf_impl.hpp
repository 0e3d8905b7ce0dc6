// The EKF's per-state-size implementations (private to estimator/): ekf.cpp dispatches on the
// state size to one of ekf_states_*.cpp, each of which instantiates EkfN for its sizes. The
// fixed-size Eigen code of every size in one file was the longest compile of the build (several
// minutes under the sanitizers, with the other core idle); split, the sizes compile in parallel.
#pragma once

#include "ekf.hpp"

#include "common.hpp"

#include "signal_gen/fastmath.hpp"

#include <Eigen/Dense>

#include <cmath>
#include <memory>
#include <stdexcept>

namespace fringe::est {

struct Ekf::Impl {
    virtual ~Impl() = default;
    virtual void init(const double* x0, const double* p0) = 0;
    virtual void predict() = 0;
    virtual bool update(const double z[2], int channels, const double* fold, double extra) = 0;
    virtual void predict_measurement(double h[2]) const = 0;
    virtual double x(int i) const = 0;
    virtual double P(int i, int j) const = 0;
    virtual int n() const = 0;
    virtual bool covariance_ok(double* min_eig) const = 0;
    virtual void reopen(int count, const double* p0) = 0;
    long long turns = 0;
    // States from this index on are held by update(): taken as known constants (their H columns
    // and gain rows zero; the Joseph form keeps P right for any gain). kMaxStates: none held.
    int hold_from = kMaxStates;
};

namespace ekf_detail {

// Diagnostics only (not per sample): dynamic size, so the eigen solver is compiled once
// rather than for every state size (defined in ekf.cpp).
bool dynamic_covariance_ok(const Eigen::MatrixXd& P, double* min_eig);

}  // namespace ekf_detail

// The channel model, defined in this header so that it is compiled in each filter size's file
// beside the update that calls it (a call into ekf.cpp cost 5 % of the two-state filter).
inline void ChannelModel::eval(const double* x, double h[2], double H[2][kMaxStates], double v[2]) const {
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

inline void ChannelModel::noise(const double v[2], double extra_var_v2, double R[3]) const {
    const double sg2 = s_.sigma_gain * s_.sigma_gain;
    const double w = white_var_ + extra_var_v2;
    R[0] = w + sg2 * v[0] * v[0];
    R[1] = sg2 * v[0] * v[1];
    R[2] = w + sg2 * v[1] * v[1];
}

namespace ekf_detail {

// Fixed sizes up to 7 states (fast per sample); one dynamic instantiation with fixed
// capacity (no allocation) for 8..9 states keeps compile time and memory in check.
template <int N, int MaxN = N>
struct EkfN final : Ekf::Impl {
    using Vec = Eigen::Matrix<double, N, 1, 0, MaxN, 1>;
    using Mat = Eigen::Matrix<double, N, N, 0, MaxN, MaxN>;
    using Mat2N = Eigen::Matrix<double, 2, N, 0, 2, MaxN>;
    using MatN2 = Eigen::Matrix<double, N, 2, 0, MaxN, 2>;
    using Row = Eigen::Matrix<double, 1, N, Eigen::RowMajor, 1, MaxN>;
    int n_ = N;
    Vec xs;
    Mat Pm, F, Q;
    // F is the identity plus at most three entries above the diagonal (the kinematics: theta
    // from omega, and with acceleration theta and omega from alpha): fi_/fj_/fv_ hold them,
    // in rows of increasing index, so that predict() applies F as row and column operations
    // (O(N) each) instead of two N x N x N products.
    int nf_ = 0, fi_[3] = {}, fj_[3] = {};
    double fv_[3] = {};
    const ChannelModel* model = nullptr;

    EkfN(const Ekf::Options& o, const ChannelModel* m) : n_(o.layout.n), model(m) {
        const double T = o.T_s;
        xs.resize(n_);
        Pm.resize(n_, n_);
        F.setIdentity(n_, n_);
        Q.setZero(n_, n_);
        F(0, 1) = T;
        if (o.kinematics == Kinematics::CV) {
            Q(0, 0) = o.q_kin * T * T * T / 3; Q(0, 1) = Q(1, 0) = o.q_kin * T * T / 2; Q(1, 1) = o.q_kin * T;
        } else {
            const int a = o.layout.alpha;
            F(0, a) = T * T / 2; F(1, a) = T;
            const double q = o.q_kin;
            Q(0, 0) = q * std::pow(T, 5) / 20; Q(0, 1) = Q(1, 0) = q * std::pow(T, 4) / 8;
            Q(0, a) = Q(a, 0) = q * std::pow(T, 3) / 6; Q(1, 1) = q * std::pow(T, 3) / 3;
            Q(1, a) = Q(a, 1) = q * T * T / 2; Q(a, a) = q * T;
        }
        const auto& L = o.layout;
        if (L.gain >= 0) Q(L.gain, L.gain) = o.q_gain_per_s * T;
        if (L.kappa >= 0) Q(L.kappa, L.kappa) = o.q_kappa_per_s * T;
        if (L.off_s >= 0) Q(L.off_s, L.off_s) = o.q_offset_v2_per_s * T;
        if (L.off_c >= 0) Q(L.off_c, L.off_c) = o.q_offset_v2_per_s * T;
        if (L.eps >= 0) Q(L.eps, L.eps) = o.q_eps_per_s * T;
        if (L.delta >= 0) Q(L.delta, L.delta) = o.q_delta_rad2_per_s * T;
        for (int i = 0; i < n_; ++i)
            for (int j = 0; j < n_; ++j)
                if (i != j && F(i, j) != 0) {
                    // the operations in predict() read row/column j before they change it
                    if (j <= i || nf_ == 3) throw std::logic_error("EkfN: F is not unit upper triangular with at most three entries");
                    fi_[nf_] = i; fj_[nf_] = j; fv_[nf_] = F(i, j); ++nf_;
                }
        xs.setZero();
        Pm.setIdentity();
    }
    void reopen(int count, const double* p0) override {
        for (int i = 0; i < count; ++i) {
            Pm.row(i).setZero();
            Pm.col(i).setZero();
            Pm(i, i) = p0[i];
        }
    }
    void init(const double* x0, const double* p0) override {
        for (int i = 0; i < n_; ++i) xs(i) = x0[i];
        Pm.setZero();
        for (int i = 0; i < n_; ++i) Pm(i, i) = p0[i];
        turns = 0;
        rewrap();
    }
    void rewrap() {
        if (xs(0) > kPi || xs(0) < -kPi) {
            const double k = std::round(xs(0) / kTwoPi);
            xs(0) -= kTwoPi * k;
            turns += static_cast<long long>(k);
        }
    }
    void predict() override {
        // x = F x, P = F P F^T + Q. Entry k adds fv times row (then column) fj to row (column)
        // fi; fj > fi, and rows are taken in increasing order, so each reads an unchanged row.
        if constexpr (N == 2 && MaxN == 2) if (nf_ == 1) {
            // the same operations on scalars (F = [1 T; 0 1]): the compiler keeps them in registers
            const double T = fv_[0], p00 = Pm(0, 0), p01 = Pm(0, 1), p10 = Pm(1, 0), p11 = Pm(1, 1);
            xs(0) += T * xs(1);
            const double r00 = p00 + T * p10, r01 = p01 + T * p11;  // row 0 += T row 1
            Pm(0, 0) = r00 + T * r01 + Q(0, 0);                      // column 0 += T column 1
            Pm(1, 0) = p10 + T * p11 + Q(1, 0);
            Pm(0, 1) = r01 + Q(0, 1);
            Pm(1, 1) = p11 + Q(1, 1);
            rewrap();
            return;
        }
        for (int k = 0; k < nf_; ++k) xs(fi_[k]) += fv_[k] * xs(fj_[k]);
        for (int k = 0; k < nf_; ++k) Pm.row(fi_[k]) += fv_[k] * Pm.row(fj_[k]);
        for (int k = 0; k < nf_; ++k) Pm.col(fi_[k]) += fv_[k] * Pm.col(fj_[k]);
        Pm += Q;
        rewrap();
    }
    void predict_measurement(double h[2]) const override {
        double H[2][kMaxStates], v[2];
        model->eval(xs.data(), h, H, v);
    }
    bool update(const double z[2], int channels, const double* fold, double extra) override {
        double h[2], Ha[2][kMaxStates], v[2], R[3];
        model->eval(xs.data(), h, Ha, v);
        model->noise(v, extra, R);
        if constexpr (N == 2 && MaxN == 2) {  // no state beyond the kinematic ones to hold
            if (channels == 3 && !fold) return update2(z, h, Ha, R);
        } else {
            // Held states are taken as known: no column in H, so the other states' gains are
            // those of a filter without them (their correlations stay in P and decay).
            for (int i = hold_from; i < n_; ++i) Ha[0][i] = Ha[1][i] = 0;
        }
        if (channels == 3) {
            Mat2N H(2, n_);
            for (int i = 0; i < n_; ++i) { H(0, i) = Ha[0][i]; H(1, i) = Ha[1][i]; }
            Eigen::Vector2d innov(z[0] - h[0], z[1] - h[1]);
            Eigen::Matrix2d Rm;
            Rm << R[0], R[1], R[1], R[2];
            if (fold) {  // a signed permutation: same information, folded coordinates (ekf-rectified)
                Eigen::Matrix2d Pf;
                Pf << fold[0], fold[1], fold[2], fold[3];
                innov = Pf * innov;
                H = Pf * H;
                Rm = Pf * Rm * Pf.transpose();
            }
            const Mat2N HP = H * Pm;
            const Eigen::Matrix2d S = HP * H.transpose() + Rm;
            // S^-1 for the 2x2 innovation covariance: positive definiteness checked first
            // (Sylvester: S00 > 0 and det > 0, the condition under which its Cholesky factor
            // exists), then the adjugate over the determinant, one division instead of the
            // two square roots and divisions of a Cholesky solve on the per-sample path.
            const double det = S(0, 0) * S(1, 1) - S(0, 1) * S(1, 0);
            if (!(S(0, 0) > 0) || !(det > 1e-300)) return false;
            const double inv_det = 1.0 / det;
            Eigen::Matrix2d Sinv;
            Sinv << S(1, 1) * inv_det, -S(0, 1) * inv_det, -S(1, 0) * inv_det, S(0, 0) * inv_det;
            // an outlier (a glitch of 5 V or 1e300 in one sample): 100 standard deviations out
            // and off the model by more than half the signal's radius, not taken in (it threw
            // the state off by up to 3e-2 rad, or into divergence). Both: a filter whose model
            // misses the signal's harmonics (ekf-ideal on a diffraction signal) sees 100 sigma
            // every cycle, but never half the radius.
            if (!(innov.dot(Sinv * innov) <= kOutlierNis) && !(innov.squaredNorm() <= 0.25 * (h[0] * h[0] + h[1] * h[1]))) return false;
            MatN2 K = (Sinv * HP).transpose();
            if (hold_from < n_) K.bottomRows(n_ - hold_from).setZero();
            xs += K * innov;
            // Joseph form expanded: (I-KH)P(I-KH)^T + KRK^T = P - K HP - (K HP)^T + K S K^T,
            // rank-2 products only (4 N^2 multiply-adds instead of 2 N^3).
            const Mat KHP = K * HP;
            const MatN2 KS = K * S;
            Pm = Pm - KHP - KHP.transpose() + KS * K.transpose();
        } else {
            const int row = channels == 1 ? 0 : 1;
            Row H(1, n_);
            for (int i = 0; i < n_; ++i) H(0, i) = Ha[row][i];
            const double r = channels == 1 ? R[0] : R[2];
            const Row HP = H * Pm;
            const double S = HP.dot(H) + r;
            if (!(S > 0)) return false;
            Vec K = HP.transpose() / S;
            if (hold_from < n_) K.tail(n_ - hold_from).setZero();
            xs += K * (z[row] - h[row]);
            // Joseph form expanded as in the two-channel update (K S K^T with scalar S)
            const Mat KHP = K * HP;
            Pm = Pm - KHP - KHP.transpose() + (S * K) * K.transpose();
        }
        Pm = 0.5 * (Pm + Pm.transpose()).eval();
        rewrap();
        return true;
    }
    // The two-state filter's update written out (ekf-diffraction CV, the most common filter):
    // the same algebra as the general path (Joseph form, the 2x2 S inverted by its adjugate,
    // the same outlier test) on scalars, each symmetric matrix computed once per pair of
    // entries, so that its dependency chain per sample is short.
    bool update2(const double z[2], const double h[2], const double Ha[2][kMaxStates], const double R[3]) {
        const double a = Ha[0][0], b = Ha[0][1], c = Ha[1][0], d = Ha[1][1];
        const double p00 = Pm(0, 0), p01 = Pm(0, 1), p11 = Pm(1, 1);
        const double i0 = z[0] - h[0], i1 = z[1] - h[1];
        // HP = H P, S = HP H^T + R
        const double hp00 = a * p00 + b * p01, hp01 = a * p01 + b * p11;
        const double hp10 = c * p00 + d * p01, hp11 = c * p01 + d * p11;
        const double s00 = hp00 * a + hp01 * b + R[0];
        const double s01 = hp00 * c + hp01 * d + R[1];
        const double s11 = hp10 * c + hp11 * d + R[2];
        const double det = s00 * s11 - s01 * s01;
        if (!(s00 > 0) || !(det > 1e-300)) return false;
        const double inv_det = 1.0 / det;
        const double si00 = s11 * inv_det, si01 = -s01 * inv_det, si11 = s00 * inv_det;
        // the outlier test of the general path
        const double nis = i0 * (si00 * i0 + si01 * i1) + i1 * (si01 * i0 + si11 * i1);
        if (!(nis <= kOutlierNis) && !(i0 * i0 + i1 * i1 <= 0.25 * (h[0] * h[0] + h[1] * h[1]))) return false;
        // K = (S^-1 HP)^T: k_ij, state i, channel j
        const double k00 = si00 * hp00 + si01 * hp10, k01 = si01 * hp00 + si11 * hp10;
        const double k10 = si00 * hp01 + si01 * hp11, k11 = si01 * hp01 + si11 * hp11;
        xs(0) += k00 * i0 + k01 * i1;
        xs(1) += k10 * i0 + k11 * i1;
        // Joseph form: (I - KH) P (I - KH)^T + K R K^T
        const double m00 = 1.0 - (k00 * a + k01 * c), m01 = -(k00 * b + k01 * d);
        const double m10 = -(k10 * a + k11 * c), m11 = 1.0 - (k10 * b + k11 * d);
        const double a00 = m00 * p00 + m01 * p01, a01 = m00 * p01 + m01 * p11;  // (I - KH) P
        const double a10 = m10 * p00 + m11 * p01, a11 = m10 * p01 + m11 * p11;
        const double b00 = k00 * R[0] + k01 * R[1], b01 = k00 * R[1] + k01 * R[2];  // K R
        const double b10 = k10 * R[0] + k11 * R[1], b11 = k10 * R[1] + k11 * R[2];
        const double n00 = a00 * m00 + a01 * m01 + b00 * k00 + b01 * k01;
        const double n01 = a00 * m10 + a01 * m11 + b00 * k10 + b01 * k11;
        const double n11 = a10 * m10 + a11 * m11 + b10 * k10 + b11 * k11;
        Pm(0, 0) = n00;
        Pm(0, 1) = Pm(1, 0) = n01;
        Pm(1, 1) = n11;
        rewrap();
        return true;
    }
    double x(int i) const override { return xs(i); }
    double P(int i, int j) const override { return Pm(i, j); }
    int n() const override { return n_; }
    bool covariance_ok(double* min_eig) const override { return dynamic_covariance_ok(Pm, min_eig); }
};

// One per file: ekf_states_2_4.cpp (2..4 states), ekf_states_5_6.cpp, ekf_states_7.cpp and
// ekf_states_dynamic.cpp (8..9). Each returns nullptr for a size it does not hold.
std::unique_ptr<Ekf::Impl> make_states_2_4(const Ekf::Options& o, const ChannelModel* m);
std::unique_ptr<Ekf::Impl> make_states_5_6(const Ekf::Options& o, const ChannelModel* m);
std::unique_ptr<Ekf::Impl> make_states_7(const Ekf::Options& o, const ChannelModel* m);
std::unique_ptr<Ekf::Impl> make_states_dynamic(const Ekf::Options& o, const ChannelModel* m);

}  // namespace ekf_detail
}  // namespace fringe::est
