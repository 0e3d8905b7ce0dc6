#include "server/analysis/bounds.hpp"

#include "signal_gen/fastmath.hpp"
#include "signal_gen/generator.hpp"

#include <Eigen/Dense>

#include <cmath>
#include <cstdio>
#include <string>

namespace fringe {

std::optional<SignalInformation> signal_information(const EncoderProfile& enc, int channels) {
    const double q = enc.adc.ideal() ? 0.0 : enc.adc.step_v();
    const double white = enc.noise.sigma_add_v * enc.noise.sigma_add_v + q * q / 12.0;
    const double sg2 = enc.noise.sigma_gain * enc.noise.sigma_gain;
    if (!(white > 0)) return std::nullopt;
    MotionProfile still;
    Generator g(enc, still, 1.0, 0);
    const double kappa = enc.kappa_nominal();
    const double gs = 1 + enc.lissajous.gain_mismatch / 2, gc = 1 - enc.lissajous.gain_mismatch / 2;
    constexpr int kGrid = 720;
    constexpr double h = 1e-5;  // central difference step, rad: truncation ~h^2/6 relative
    SignalInformation out;
    out.j_min = 1e300;
    for (int k = 0; k < kGrid; ++k) {
        const double th = -kPi + kTwoPi * (k + 0.5) / kGrid;
        double sp, cp, sm, cm, rs, rc;
        g.clean_channels(th + h, kappa, sp, cp);
        g.clean_channels(th - h, kappa, sm, cm);
        g.raw_channels(th, kappa, rs, rc);
        const Eigen::Vector2d d((sp - sm) / (2 * h), (cp - cm) / (2 * h));
        const Eigen::Vector2d v(gs * rs, gc * rc);
        double J;
        if (channels == 1) J = d(0) * d(0) / (white + sg2 * v(0) * v(0));
        else {
            const Eigen::Matrix2d R = white * Eigen::Matrix2d::Identity() + sg2 * v * v.transpose();
            Eigen::LDLT<Eigen::Matrix2d> ldlt(R);
            if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return std::nullopt;
            J = d.dot(ldlt.solve(d));
        }
        out.j_mean += J / kGrid;
        out.j_min = std::min(out.j_min, J);
        out.j_max = std::max(out.j_max, J);
    }
    out.r_rad2 = 1.0 / out.j_mean;
    return out;
}

TrackingBound tracking_bound(est::Kinematics kin, double q, double r, double T) {
    const int n = kin == est::Kinematics::CV ? 2 : 3;
    Eigen::MatrixXd F = Eigen::MatrixXd::Identity(n, n), Q = Eigen::MatrixXd::Zero(n, n);
    F(0, 1) = T;
    if (n == 2) {
        Q << T * T * T / 3, T * T / 2, T * T / 2, T;
    } else {
        F(0, 2) = T * T / 2; F(1, 2) = T;
        Q << std::pow(T, 5) / 20, std::pow(T, 4) / 8, std::pow(T, 3) / 6,
             std::pow(T, 4) / 8, std::pow(T, 3) / 3, T * T / 2,
             std::pow(T, 3) / 6, T * T / 2, T;
    }
    Q *= q;
    return steady_state_bound(F, Q, r);
}

TrackingBound steady_state_bound(const Eigen::MatrixXd& F, const Eigen::MatrixXd& Q, double r) {
    const auto n = F.rows();
    Eigen::RowVectorXd H = Eigen::RowVectorXd::Zero(n);
    H(0) = 1;
    Eigen::MatrixXd Pp = Eigen::MatrixXd::Identity(n, n) * r;  // a posteriori
    Eigen::VectorXd K(n);
    TrackingBound b;
    for (int it = 1; it <= 50'000'000; ++it) {
        const Eigen::MatrixXd Pm = F * Pp * F.transpose() + Q;
        const double S = Pm(0, 0) + r;
        K = Pm.col(0) / S;
        Eigen::MatrixXd Pn = Pm - K * Pm.row(0);
        Pn = 0.5 * (Pn + Pn.transpose()).eval();
        const double change = (Pn - Pp).cwiseAbs().maxCoeff() / Pn.cwiseAbs().maxCoeff();
        Pp = Pn;
        b.iterations = it;
        if (change < 1e-14 && it > 10) break;
    }
    b.pcrb_rad2 = Pp(0, 0);
    b.pcrb_omega_rad2_s2 = Pp(1, 1);
    b.gain_theta = K(0);
    b.gain_omega_per_s = K(1);
    // Noise-only part: e+ = A e+ + K v with A = (I - K H) F (no process noise on a
    // deterministic trajectory); P = sum_k A^k (K r K') A'^k by doubling.
    Eigen::MatrixXd A = (Eigen::MatrixXd::Identity(n, n) - K * H) * F;
    Eigen::MatrixXd P = K * r * K.transpose();
    for (int i = 0; i < 80; ++i) {
        const Eigen::MatrixXd add = A * P * A.transpose();
        P += add;
        A = (A * A).eval();
        if (add.cwiseAbs().maxCoeff() <= 1e-17 * P.cwiseAbs().maxCoeff()) break;
    }
    b.noise_only_rad2 = P(0, 0);
    return b;
}

TrackingBound kalata_cv(double sigma_a2, double r, double T) {
    const double sigma_a = std::sqrt(sigma_a2);
    const double lambda = sigma_a * T * T / std::sqrt(r);
    const double l2 = lambda * lambda, s = std::sqrt(l2 + 8 * lambda);
    const double alpha = -(l2 + 8 * lambda - (lambda + 4) * s) / 8;
    const double beta = (l2 + 4 * lambda - lambda * s) / 4;
    TrackingBound b;
    b.pcrb_rad2 = alpha * r;
    b.pcrb_omega_rad2_s2 = beta * (alpha - beta / 2) / (1 - alpha) * r / (T * T);
    b.gain_theta = alpha;
    b.gain_omega_per_s = beta / T;
    return b;
}

EncoderProfile delivered_profile(const EncoderProfile& enc, const dev::ConverterInfo& c, nlohmann::json* basis) {
    EncoderProfile out = enc;
    const double q_enc = enc.adc.ideal() ? 0.0 : enc.adc.step_v();
    const double q_dac = c.known ? c.dac_q_v() : 0.0, q_adc = c.known ? c.adc_q_v() : 0.0;
    const double noise = c.known ? c.noise_at_adc_v : 0.0, added = c.known ? c.added_noise_v : 0.0;
    const double white2 = enc.noise.sigma_add_v * enc.noise.sigma_add_v + q_enc * q_enc / 12 + added * added;
    out.noise.sigma_add_v = std::sqrt(white2);
    out.adc = Quantizer{};  // folded into the white noise above
    out.adc.bits = 0;
    if (basis) {
        nlohmann::json assumptions = nlohmann::json::array();
        assumptions.push_back("quantisation as white noise of q^2/12 per converter (valid when the signal spans many codes)");
        if (!c.known) assumptions.push_back("the device does not describe its converter: the bound is the encoder signal's alone");
        else if (!c.note.empty()) assumptions.push_back(c.note);
        *basis = {{"encoder_noise_v", enc.noise.sigma_add_v}, {"encoder_adc_step_v", q_enc}, {"device_dac_step_v", q_dac},
                  {"device_adc_step_v", q_adc}, {"device_noise_v", noise}, {"device_added_noise_v", added}, {"white_noise_v", out.noise.sigma_add_v},
                  {"gain_noise", enc.noise.sigma_gain}, {"assumptions", assumptions}};
    }
    return out;
}

nlohmann::json bounds_json(const EncoderProfile& truth, const est::Estimator& e, double fs,
                           std::uint64_t scored, double rms_rad, int channels) {
    nlohmann::json j;
    const auto info = signal_information(truth, channels);
    if (!info) {
        j["note"] = "the signal has no noise: every bound is zero and efficiency undefined";
        return j;
    }
    const double r = info->r_rad2, T = 1.0 / fs;
    const double mse = rms_rad * rms_rad;
    j["fisher_information_per_rad2"] = {{"mean", info->j_mean}, {"min", info->j_min}, {"max", info->j_max}};
    j["per_sample_crb_rad"] = std::sqrt(r);
    if (scored > 1) {
        const double K = static_cast<double>(scored);
        j["batch_bound_rad"] = {{"window_centre", std::sqrt(r / K)},
                                {"last_sample", std::sqrt(r * (4 * K - 2) / (K * (K + 1)))}};
    }
    double graded = r;
    std::string against = "per_sample_crb";
    if (auto p = e.prior()) {
        const double wn = kTwoPi * p->natural_freq_hz;
        const double q = p->kinematics == est::Kinematics::CV ? std::pow(wn, 4) * r * T : std::pow(wn, 6) * r * T;
        const auto b = tracking_bound(p->kinematics, q, r, T);
        j["prior"] = {{"kinematics", p->kinematics == est::Kinematics::CV ? "cv" : "ca"},
                      {"natural_freq_hz", p->natural_freq_hz}, {"q", q}};
        j["pcrb_rad"] = std::sqrt(b.pcrb_rad2);
        j["pcrb_noise_only_rad"] = std::sqrt(b.noise_only_rad2);
        j["pcrb_omega_rad_s"] = std::sqrt(b.pcrb_omega_rad2_s2);
        // Deterministic motion (every fringe motion profile): grade against the noise-only part.
        graded = b.noise_only_rad2;
        against = "pcrb_noise_only";
        if (mse > 0) j["efficiency_pcrb"] = b.pcrb_rad2 / mse;
    } else if (e.bound_class() == est::BoundClass::Tracker) {
        against = "";  // no declared prior: no tracking bound to grade against
    }
    if (!against.empty() && mse > 0) {
        const double eff = graded / mse;
        j["efficiency"] = eff;
        j["efficiency_against"] = against;
        // No estimator beats the bound it is graded against by more than the scatter of a
        // finite run: well above 1, the bound is not the estimator's (a tracker declaring a wider
        // prior than it runs, or a tracker declared memoryless). Named, and no limit passes on it.
        if (eff > kMaxCredibleEfficiency) {
            char b[64];
            std::snprintf(b, sizeof b, "%.3g", eff);
            const auto p = e.prior();
            std::string why = std::string("efficiency ") + b + " against " + against + " is above " + std::to_string(kMaxCredibleEfficiency).substr(0, 3) +
                              ": no estimator beats the bound of its own model by that much, so the bound is not this estimator's: ";
            if (p) {
                std::snprintf(b, sizeof b, "%.4g", p->natural_freq_hz);
                why += std::string("its declared prior (") + (p->kinematics == est::Kinematics::CV ? "cv" : "ca") + ", natural_freq_hz " + b +
                       ") is likely wider than the loop it runs; declare the prior it actually uses";
            } else {
                why += "it is graded as memoryless (per-sample bound) but averages over samples like a tracker; declare it a tracker with its prior";
            }
            j["efficiency_not_credible"] = why;
        }
    } else {
        j["efficiency"] = nullptr;
        j["efficiency_against"] = against.empty() ? "none (the estimator declares no prior)" : against;
    }
    return j;
}

}  // namespace fringe
