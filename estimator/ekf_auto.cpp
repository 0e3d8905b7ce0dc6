// ekf-auto (issue 13): an estimator told nothing. A phase tracker whose measurement model is a
// Fourier shape table per channel, learnt by a slower, phase-gated least-squares identifier.
//
//   shape:   h_ch(theta) = c_ch . phi(theta),  phi = [1, cos theta, sin theta, ..., cos M theta, sin M theta]
//   tracker: CA kinematics [theta, omega, alpha] (white jerk, q = wn^6 r T; covers constant
//            speed, acceleration, reversals and standstill without a CV/CA choice); each
//            sample's two channels become one Gauss-Newton phase measurement
//            nu = h' R^-1 (z - h) / J with variance 1/J, J = h' R^-1 h' (the same update as
//            a two-channel EKF with H = [h', 0, 0]), R the residual covariance it measures.
//   identifier: normal equations of z_ch on phi(theta_hat) with exponential forgetting per
//            accepted point; a point is accepted only when the phase moved 2*pi/points_per_cycle
//            since the last one (a standstill adds nothing, so the shape holds still and
//            cannot drift); solved every refit_points points.
//   convention (MODEL.md 2.2): theta is defined by the fundamental of the sin channel
//            (proportional to sin theta). After each solve, the phase phi1 of that fundamental is
//            moved into the tracker (theta += phi1) and the coefficients and normal equations
//            are rotated to match, so the shape cannot rotate the phase.
//   order:   the highest harmonic whose amplitude stands above 4 standard errors in either
//            channel (max_order at most), at least 1.
//   stages:  acquisition (atan2 line fit, output invalid) -> bootstrap (order 1, until the
//            identifier has seen bootstrap_cycles electrical cycles; output valid) -> full order.
//   guard:   the LockMonitor of common.hpp; on loss of lock the shape is discarded and the
//            tracker re-acquires (safe mode), output invalid meanwhile.
#include "common.hpp"
#include "registry_parts.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>

namespace fringe::est {

namespace {

constexpr int kMaxOrder = 12;
constexpr int kMaxBasis = 2 * kMaxOrder + 1;

class EkfAuto final : public Estimator {
public:
    static std::vector<ParamInfo> params() {
        return {
            {"natural_freq_hz", "Hz", ParamType::Number, 100.0, 1e-3, 1e7, {},
             "tracking natural frequency fn of the CA tracker; q = wn^6*r*T with r from the learnt shape and measured noise"},
            {"max_order", "", ParamType::Integer, 8, 6, kMaxOrder, {},
             "highest harmonic of the shape table the identifier fits; the tracker uses those that stand above the noise"},
            {"memory_cycles", "cycles", ParamType::Number, 16.0, 1.0, 1e6, {},
             "identifier forgetting horizon, in electrical cycles of motion (shorter follows gap run-out and light drift faster, longer averages more noise)"},
            {"points_per_cycle", "points", ParamType::Integer, 64, 8, 4096, {},
             "phase gate: a sample enters the identifier after the phase moved 2*pi/points_per_cycle since the last one"},
            {"refit_points", "points", ParamType::Integer, 32, 1, 1e6, {}, "identifier solve every this many accepted points"},
            {"bootstrap_cycles", "cycles", ParamType::Number, 2.0, 1.0, 1e4, {},
             "electrical cycles seen with a fundamental-only shape before the full order is fitted"},
            {"noise_memory_samples", "samples", ParamType::Number, 2000.0, 10, 1e9, {},
             "time constant of the residual covariance estimate R"},
            acquisition_param(),
            LockMonitor::threshold_param(),
        };
    }

    void reset(const EstimatorConfig& cfg) override {
        const Params p = resolve_params(params(), cfg.params);
        if (!(cfg.sample_rate_hz > 0)) throw ConfigError("sample_rate_hz", "must be positive");
        fs_ = cfg.sample_rate_hz;
        T_ = 1.0 / fs_;
        fn_ = p.number("natural_freq_hz");
        wn_ = kTwoPi * fn_;
        if (wn_ * T_ > 0.5) throw ConfigError("params.natural_freq_hz", "too high for the sample rate (wn*T must be < 0.5)");
        max_order_ = static_cast<int>(p.integer("max_order"));
        ppc_ = static_cast<int>(p.integer("points_per_cycle"));
        gate_ = kTwoPi / ppc_;
        keep_ = 1.0 - 1.0 / (p.number("memory_cycles") * ppc_);
        refit_ = static_cast<long long>(p.integer("refit_points"));
        bootstrap_points_ = static_cast<long long>(p.number("bootstrap_cycles") * ppc_);
        noise_a_ = 1.0 / p.number("noise_memory_samples");
        acq_n_ = static_cast<std::size_t>(p.integer("acquisition_samples"));
        Calibration none;
        none.prepare();
        cal_ = none;
        lock_.reset(none, p.number("lock_threshold_rad"));
        nonfinite_ = 0;
        refits_ = 0;
        restart();
    }

    void process(InputSpan in, OutputSpan out) override {
        const std::size_t n = in.size();
        for (std::size_t i = 0; i < n; ++i) {
            const double zs = in.sin_v[i], zc = in.cos_v[i];
            if (!(std::isfinite(zs) && std::isfinite(zc))) {
                ++nonfinite_;
                if (acq_.done()) predict();
                out.theta_rad[i] = theta_out();
                out.omega_rad_s[i] = x_[1];
                out.valid[i] = 0;
                continue;
            }
            lock_.reference(zs, zc);
            if (!acq_.done()) {
                acq_sum_ += zs * zs + zc * zc;
                const bool done = acq_.add(zs, zc);
                out.theta_rad[i] = lock_.anchor(acq_.last_atan2_rad());
                out.omega_rad_s[i] = 0;
                out.valid[i] = 0;
                if (reacquiring_) lock_.count_invalid();
                if (done) start();
                continue;
            }
            predict();
            update(zs, zc);
            out.theta_rad[i] = theta_out();
            out.omega_rad_s[i] = x_[1];
            out.valid[i] = 1;
            if (!lock_.check(out.theta_rad[i])) {
                out.valid[i] = 0;
                lock_.count_invalid();
                restart();
                reacquiring_ = true;
                continue;
            }
            learn(zs, zc);
        }
    }

    BoundClass bound_class() const override { return BoundClass::Tracker; }
    std::optional<TrackingPrior> prior() const override { return TrackingPrior{Kinematics::CA, fn_}; }

    nlohmann::json state() const override {
        nlohmann::json j{{"stage", !acq_.done() ? "acquisition" : (full_ ? "tracking" : "bootstrap")},
                         {"order", order_}, {"refits", refits_}, {"accepted_points", accepted_},
                         {"nonfinite_samples", nonfinite_}, {"loss_of_lock", lock_.to_json()}};
        auto coeffs = [&](const std::array<double, kMaxBasis>& c) {
            nlohmann::json h = nlohmann::json::array();
            for (int m = 1; m <= order_; ++m) h.push_back({{"order", m}, {"cos_v", c[2 * m - 1]}, {"sin_v", c[2 * m]}});
            return nlohmann::json{{"dc_v", c[0]}, {"harmonics", h}};
        };
        j["shape_sin"] = coeffs(cs_);
        j["shape_cos"] = coeffs(cc_);
        j["noise_cov_v2"] = {R_[0], R_[1], R_[2]};
        j["r_model_rad2"] = r_bar_;
        return j;
    }

private:
    using MatB = Eigen::Matrix<double, kMaxBasis, kMaxBasis>;
    using VecB = Eigen::Matrix<double, kMaxBasis, 1>;

    double theta_out() const { return x_[0] + kTwoPi * static_cast<double>(turns_); }

    // Back to acquisition with a fundamental-only shape: the safe mode.
    void restart() {
        acq_.reset(acq_n_, fs_, cal_);
        acq_sum_ = 0;
        A_.setZero();
        bs_.setZero();
        bc_.setZero();
        cs_.fill(0.0);
        cc_.fill(0.0);
        order_ = 1;
        full_ = false;
        accepted_ = 0;
        have_last_ = false;
        reacquiring_ = false;
    }

    void start() {
        // fundamental-only shape of the Lissajous radius over the acquisition window
        const double amp = std::sqrt(acq_sum_ / static_cast<double>(acq_.samples()));
        cs_.fill(0.0);
        cc_.fill(0.0);
        cs_[2] = amp;  // sin theta
        cc_[1] = amp;  // cos theta
        // conservative noise until residuals are measured: 1 % of the amplitude
        const double v = std::pow(0.01 * std::max(amp, 1e-9), 2);
        R_ = {v, 0.0, v};
        noise_inv();
        update_prior();
        const double th = lock_.anchor(acq_.theta_rad());
        const double fr = wrap_pi(th);
        turns_ = std::llround((th - fr) / kTwoPi);
        x_ = {fr, acq_.omega_rad_s(), 0.0};
        std::memset(P_, 0, sizeof P_);
        P_[0][0] = 0.05 * 0.05;
        P_[1][1] = std::pow(kTwoPi * 5, 2);
        P_[2][2] = std::pow(kTwoPi * 1000, 2);
        sl_ = {th, acq_.omega_rad_s(), 0.0};
        settled_ = 0;
        sl_ok_ = false;
        lock_.rearm();
        reacquiring_ = false;
    }

    void noise_inv() {
        const double det = R_[0] * R_[2] - R_[1] * R_[1];
        const double d = det > 0 ? det : R_[0] * R_[2];
        Ri_ = {R_[2] / d, -R_[1] / d, R_[0] / d};
    }

    // Mean information J_bar over a cycle from the shape and R; q = wn^6 r T (CA), r = 1/J_bar.
    void update_prior() {
        constexpr int kGrid = 64;
        double sum = 0;
        for (int k = 0; k < kGrid; ++k) {
            double h[2], d[2];
            eval(kTwoPi * k / kGrid, h, d);
            sum += d[0] * d[0] * Ri_[0] + 2 * d[0] * d[1] * Ri_[1] + d[1] * d[1] * Ri_[2];
        }
        const double jbar = sum / kGrid;
        r_bar_ = jbar > 0 ? 1.0 / jbar : 1.0;
        const double q = std::pow(wn_, 6) * r_bar_ * T_;
        const double T = T_;
        Q_[0][0] = q * std::pow(T, 5) / 20; Q_[0][1] = Q_[1][0] = q * std::pow(T, 4) / 8;
        Q_[0][2] = Q_[2][0] = q * std::pow(T, 3) / 6; Q_[1][1] = q * std::pow(T, 3) / 3;
        Q_[1][2] = Q_[2][1] = q * T * T / 2; Q_[2][2] = q * T;
    }

    // Shape value and derivative in theta for both channels.
    void eval(double theta, double h[2], double d[2]) const {
        double s1, c1;
        sincos_small(wrap_pi(theta), s1, c1);
        double hs = cs_[0], hc = cc_[0], ds = 0, dc = 0;
        double cm = c1, sm = s1;
        for (int m = 1; m <= order_; ++m) {
            const double as = cs_[2 * m - 1], bs = cs_[2 * m], ac = cc_[2 * m - 1], bc = cc_[2 * m];
            hs += as * cm + bs * sm;
            hc += ac * cm + bc * sm;
            ds += m * (bs * cm - as * sm);
            dc += m * (bc * cm - ac * sm);
            const double cn = cm * c1 - sm * s1;
            sm = sm * c1 + cm * s1;
            cm = cn;
        }
        h[0] = hs; h[1] = hc; d[0] = ds; d[1] = dc;
    }

    void predict() {
        const double T = T_;
        x_[0] += T * x_[1] + 0.5 * T * T * x_[2];
        x_[1] += T * x_[2];
        if (x_[0] > kPi || x_[0] < -kPi) {
            const double k = std::round(x_[0] / kTwoPi);
            x_[0] -= kTwoPi * k;
            turns_ += static_cast<long long>(k);
        }
        // P = F P F' + Q, F = [[1, T, T^2/2], [0, 1, T], [0, 0, 1]]
        const double h2 = 0.5 * T * T;
        double FP[3][3];
        for (int j = 0; j < 3; ++j) {
            FP[0][j] = P_[0][j] + T * P_[1][j] + h2 * P_[2][j];
            FP[1][j] = P_[1][j] + T * P_[2][j];
            FP[2][j] = P_[2][j];
        }
        for (int i = 0; i < 3; ++i) {
            P_[i][0] = FP[i][0] + T * FP[i][1] + h2 * FP[i][2] + Q_[i][0];
            P_[i][1] = FP[i][1] + T * FP[i][2] + Q_[i][1];
            P_[i][2] = FP[i][2] + Q_[i][2];
        }
    }

    void update(double zs, double zc) {
        double h[2], d[2];
        eval(x_[0], h, d);
        const double rs = zs - h[0], rc = zc - h[1];
        // residual covariance (a priori residuals; their phase part is negligible once locked)
        R_[0] += noise_a_ * (rs * rs - R_[0]);
        R_[1] += noise_a_ * (rs * rc - R_[1]);
        R_[2] += noise_a_ * (rc * rc - R_[2]);
        if (++since_noise_ == 256) {  // R and q together, so the tracker's bandwidth stays fn
            since_noise_ = 0;
            noise_inv();
            update_prior();
        }
        const double gs = d[0] * Ri_[0] + d[1] * Ri_[1], gc = d[0] * Ri_[1] + d[1] * Ri_[2];  // R^-1 h'
        const double J = gs * d[0] + gc * d[1];
        if (!(J > 0)) return;
        const double nu = (gs * rs + gc * rc) / J, r = 1.0 / J;
        const double S = P_[0][0] + r;
        const double K[3] = {P_[0][0] / S, P_[1][0] / S, P_[2][0] / S};
        for (int i = 0; i < 3; ++i) x_[i] += K[i] * nu;
        const double p0[3] = {P_[0][0], P_[0][1], P_[0][2]};
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) P_[i][j] -= K[i] * p0[j];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < i; ++j) P_[i][j] = P_[j][i] = 0.5 * (P_[i][j] + P_[j][i]);
    }

    // The identifier's phase: a type-3 loop (zero lag under constant acceleration, gains of
    // the continuous CA filter 2wn, 2wn^2, wn^3) on the tracker's phase, with a bandwidth an
    // eighth of the electrical frequency. The tracker follows any shape error that varies
    // slower than fn, so learning from its phase would let a warped shape and a warped phase
    // agree with each other; this loop does not follow the k-per-cycle wiggles of a wrong
    // shape, so the shape is learnt against a phase that is smooth in time.
    void slow_loop(double theta) {
        const double T = T_;
        sl_[0] += T * sl_[1] + 0.5 * T * T * sl_[2];
        sl_[1] += T * sl_[2];
        const double f_elec = std::fabs(x_[1]) / kTwoPi;
        const double wl = kTwoPi * std::clamp(f_elec / 8.0, 0.5, fn_);
        const double e = theta - sl_[0];
        sl_[0] += 2 * wl * T * e;
        sl_[1] += 2 * wl * wl * T * e;
        sl_[2] += wl * wl * wl * T * e;
        // settled: run for 4 time constants while the motion is fast against its band (at a
        // reversal or standstill the shape cannot be told from the motion: no learning)
        const bool ok = std::fabs(e) < 0.5 && f_elec > 4.0;
        settled_ = ok ? settled_ + 1 : 0;
        sl_ok_ = settled_ > static_cast<long long>(4.0 / (wl * T));
    }

    void learn(double zs, double zc) {
        slow_loop(theta_out());
        if (!sl_ok_) return;
        const double th = sl_[0];
        if (have_last_ && std::fabs(th - last_) < gate_) return;
        last_ = th;
        have_last_ = true;
        const int nb = 2 * max_order_ + 1;
        VecB f = VecB::Zero();
        double s1, c1;
        sincos_small(wrap_pi(th), s1, c1);
        f(0) = 1.0;
        double cm = c1, sm = s1;
        for (int m = 1; m <= max_order_; ++m) {
            f(2 * m - 1) = cm;
            f(2 * m) = sm;
            const double cn = cm * c1 - sm * s1;
            sm = sm * c1 + cm * s1;
            cm = cn;
        }
        A_.topLeftCorner(nb, nb) = keep_ * A_.topLeftCorner(nb, nb) + f.head(nb) * f.head(nb).transpose();
        bs_.head(nb) = keep_ * bs_.head(nb) + zs * f.head(nb);
        bc_.head(nb) = keep_ * bc_.head(nb) + zc * f.head(nb);
        ++accepted_;
        if (accepted_ % refit_ == 0 && accepted_ >= 2 * ppc_ / 4) solve();
    }

    void solve() {
        if (!full_ && accepted_ >= bootstrap_points_) full_ = true;
        const int fit_order = full_ ? max_order_ : 1;
        const int nb = 2 * fit_order + 1;
        Eigen::MatrixXd M = A_.topLeftCorner(nb, nb);
        M.diagonal().array() += 1e-12 * M.diagonal().maxCoeff();
        Eigen::LDLT<Eigen::MatrixXd> ldlt(M);
        if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return;
        const Eigen::VectorXd ss = ldlt.solve(bs_.head(nb)), sc = ldlt.solve(bc_.head(nb));
        if (!ss.allFinite() || !sc.allFinite()) return;
        // phase convention: the sin channel's fundamental a1 cos + b1 sin = R sin(theta + phi1)
        const double phi1 = std::atan2(ss(1), ss(2));
        if (!(std::hypot(ss(1), ss(2)) > 0)) return;
        std::array<double, kMaxBasis> ns{}, nc{};
        for (int i = 0; i < nb; ++i) { ns[i] = ss(i); nc[i] = sc(i); }
        // rotate into theta' = theta + phi1: coefficients and the normal equations (all orders)
        Eigen::Matrix<double, kMaxBasis, kMaxBasis> Tm = Eigen::Matrix<double, kMaxBasis, kMaxBasis>::Identity();
        for (int m = 1; m <= max_order_; ++m) {
            const double c = std::cos(m * phi1), s = std::sin(m * phi1);
            Tm(2 * m - 1, 2 * m - 1) = c; Tm(2 * m - 1, 2 * m) = s;
            Tm(2 * m, 2 * m - 1) = -s; Tm(2 * m, 2 * m) = c;
            if (m <= fit_order) {
                const double a = ns[2 * m - 1], b = ns[2 * m];
                ns[2 * m - 1] = c * a - s * b; ns[2 * m] = s * a + c * b;
                const double a2 = nc[2 * m - 1], b2 = nc[2 * m];
                nc[2 * m - 1] = c * a2 - s * b2; nc[2 * m] = s * a2 + c * b2;
            }
        }
        A_ = (Tm.transpose() * A_ * Tm).eval();
        bs_ = (Tm.transpose() * bs_).eval();
        bc_ = (Tm.transpose() * bc_).eval();
        x_[0] += phi1;
        last_ += phi1;
        sl_[0] += phi1;
        // order: the highest harmonic above 4 standard errors (noise from R, points from A)
        int order = 1;
        if (full_) {
            const double n_eff = std::max(A_(0, 0), 1.0);
            const double se = std::sqrt(2.0 * std::max(R_[0], R_[2]) / n_eff);
            for (int m = 2; m <= fit_order; ++m)
                if (std::hypot(ns[2 * m - 1], ns[2 * m]) > 4 * se || std::hypot(nc[2 * m - 1], nc[2 * m]) > 4 * se) order = m;
        }
        cs_ = ns;
        cc_ = nc;
        order_ = order;
        noise_inv();
        update_prior();
        ++refits_;
    }

    double fs_ = 1, T_ = 1, fn_ = 100, wn_ = 0;
    int max_order_ = 8, ppc_ = 64, order_ = 1;
    double gate_ = 0.1, keep_ = 1, noise_a_ = 1e-3, r_bar_ = 0;
    int since_noise_ = 0;
    long long refit_ = 32, bootstrap_points_ = 128, accepted_ = 0, refits_ = 0, nonfinite_ = 0;
    bool full_ = false, have_last_ = false, reacquiring_ = false;
    double last_ = 0, acq_sum_ = 0;
    std::size_t acq_n_ = 200;
    Calibration cal_;
    Acquisition acq_;
    LockMonitor lock_;
    // tracker
    std::array<double, 3> x_{}, sl_{};
    long long settled_ = 0;
    bool sl_ok_ = false;
    long long turns_ = 0;
    double P_[3][3] = {}, Q_[3][3] = {};
    std::array<double, 3> R_{}, Ri_{};
    // shape and identifier
    std::array<double, kMaxBasis> cs_{}, cc_{};
    MatB A_ = MatB::Zero();
    VecB bs_ = VecB::Zero(), bc_ = VecB::Zero();
};

}  // namespace

void register_ekf_auto(std::vector<EstimatorInfo>& r) {
    r.push_back({"ekf-auto",
                 "Told nothing: a CA phase tracker whose measurement model is a Fourier shape table per channel (offsets, gains, "
                 "quadrature, harmonics), learnt by a slower phase-gated least-squares identifier with forgetting; measures its own noise; "
                 "guarded by a loss-of-lock monitor",
                 EkfAuto::params(), [] { return std::make_unique<EkfAuto>(); }});
}

}  // namespace fringe::est
