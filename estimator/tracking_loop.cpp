// pll2: the ratiometric type-II tracking loop of MODEL.md 4.2 (paper eqs 5-7).
//   e = sn*cos(theta-) - cn*sin(theta-), divided by |(sn, cn)| (ratiometric: independent of
//   the signal amplitude, so e = sin(theta - theta-) for a clean signal);
//   theta+ = theta- + K1*e, omega+ = omega- + K2*e, theta-(k+1) = theta+ + T*omega+,
//   K1 = 2*zeta*wn*T, K2 = wn^2*T.
#include "common.hpp"
#include "registry_parts.hpp"

namespace fringe::est {

namespace {

class Pll2 final : public Estimator {
public:
    static std::vector<ParamInfo> params() {
        auto p = calibration_params();
        p.push_back({"natural_freq_hz", "Hz", ParamType::Number, 100.0, 1e-3, 1e7, {},
                     "loop natural frequency fn (wn = 2*pi*fn)"});
        p.push_back({"damping", "", ParamType::Number, 0.70710678118654752, 0.05, 10, {},
                     "damping ratio zeta; 1/sqrt(2) makes the loop the steady-state Kalman filter of the CV model"});
        p.push_back(acquisition_param());
        return p;
    }
    void reset(const EstimatorConfig& cfg) override {
        const Params p = resolve_params(params(), cfg.params);
        if (!(cfg.sample_rate_hz > 0)) throw ConfigError("sample_rate_hz", "must be positive");
        T_ = 1.0 / cfg.sample_rate_hz;
        fn_ = p.number("natural_freq_hz");
        const double wn = kTwoPi * fn_;
        if (wn * T_ > 0.5) throw ConfigError("params.natural_freq_hz", "too high for the sample rate (wn*T must be < 0.5)");
        k1_ = 2 * p.number("damping") * wn * T_;
        k2_ = wn * wn * T_;
        cal_ = nominal_calibration(cfg.encoder, p);
        acq_.reset(static_cast<std::size_t>(p.integer("acquisition_samples")), cfg.sample_rate_hz, cal_);
        frac_ = omega_ = 0;
        turns_ = 0;
    }
    void process(InputSpan in, OutputSpan out) override {
        const std::size_t n = in.size();
        for (std::size_t i = 0; i < n; ++i) {
            const double s = in.sin_v[i], c = in.cos_v[i];
            if (!acq_.done()) {
                const bool done = acq_.add(s, c);
                out.theta_rad[i] = acq_.last_atan2_rad();
                out.omega_rad_s[i] = 0;
                out.valid[i] = 0;
                if (done) {
                    const double th = acq_.theta_rad();
                    omega_ = acq_.omega_rad_s();
                    frac_ = wrap_pi(th);
                    turns_ = std::llround((th - frac_) / kTwoPi);
                    frac_ += T_ * omega_;  // prediction for the next sample
                }
                continue;
            }
            double sn, cn, sp, cp;
            cal_.normalise(s, c, sn, cn);
            fast_sincos(frac_, sp, cp);
            const double mag = std::sqrt(sn * sn + cn * cn);
            const double e = mag > 0 ? (sn * cp - cn * sp) / mag : 0.0;
            frac_ += k1_ * e;
            omega_ += k2_ * e;
            out.theta_rad[i] = frac_ + kTwoPi * static_cast<double>(turns_);
            out.omega_rad_s[i] = omega_;
            out.valid[i] = 1;
            frac_ += T_ * omega_;
            if (frac_ > kPi) { frac_ -= kTwoPi; ++turns_; }
            else if (frac_ < -kPi) { frac_ += kTwoPi; --turns_; }
        }
    }
    std::optional<TrackingPrior> prior() const override { return TrackingPrior{Kinematics::CV, fn_}; }
    nlohmann::json state() const override { return {{"calibration", cal_.to_json()}, {"k1", k1_}, {"k2_rad_s", k2_}}; }

private:
    double T_ = 1, fn_ = 100, k1_ = 0, k2_ = 0;
    Calibration cal_;
    Acquisition acq_;
    double frac_ = 0, omega_ = 0;  // predicted phase in (-pi, pi] (+ turns), rate
    long long turns_ = 0;
};

}  // namespace

void register_tracking_loop(std::vector<EstimatorInfo>& r) {
    r.push_back({"pll2", "Ratiometric type-II tracking loop (MODEL.md 4.2), natural frequency and damping as parameters",
                 Pll2::params(), [] { return std::make_unique<Pll2>(); }});
}

}  // namespace fringe::est
