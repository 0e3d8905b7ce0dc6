// pll2: the ratiometric type-II tracking loop of MODEL.md 4.2 (paper eqs 5-7).
//   e = sn*cos(theta-) - cn*sin(theta-), divided by |(sn, cn)| (ratiometric: independent of
//   the signal amplitude, so e = sin(theta - theta-) for a clean signal);
//   theta+ = theta- + K1*e, omega+ = omega- + K2*e, theta-(k+1) = theta+ + T*omega+,
//   K1 = 2*zeta*wn*T, K2 = wn^2*T.
// Lock detector: the in-phase product cos(theta - theta-) = sn*cos(theta-) + cn*sin(theta-)
// (ratiometric), low-passed over ~8 samples, goes negative before the loop can slip a cycle
// (the error must pass pi/2). Then the sample is invalid, the event is counted and the loop
// re-acquires from atan2, its turn count taken nearest the phase it last held, extrapolated.
#include "common.hpp"
#include "correction.hpp"
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
        p.push_back(correction_param());
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
        corr_ = correction_from_params(p, cal_);
        k_ = cal_.coeffs();
        acq_n_ = static_cast<std::size_t>(p.integer("acquisition_samples"));
        acq_.reset(acq_n_, cfg.sample_rate_hz, cal_);
        frac_ = omega_ = 0;
        inphase_ = 1.0;
        reacquiring_ = false;
        lol_events_ = lol_invalid_ = 0;
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
                if (reacquiring_) ++lol_invalid_;
                if (done) {
                    double th = acq_.theta_rad();
                    if (reacquiring_) {
                        // nearest the last locked phase carried on at the last locked rate
                        const double guess = lost_theta_ + lost_omega_ * T_ * static_cast<double>(acq_.samples());
                        th = guess + wrap_pi(th - guess);
                        reacquiring_ = false;
                    }
                    inphase_ = 1.0;
                    omega_ = acq_.omega_rad_s();
                    frac_ = wrap_pi(th);
                    turns_ = std::llround((th - frac_) / kTwoPi);
                    frac_ += T_ * omega_;  // prediction for the next sample
                    sincos_small(frac_, ps_, pc_);
                    since_sync_ = 0;
                }
                continue;
            }
            double sn = (s - k_.os) * k_.inv_as;
            double cn = ((c - k_.oc) * k_.inv_ac + sn * k_.sin_d) * k_.inv_cos_d;
            if (corr_) {
                // The loop tracks the corrected phase of the signals (docs/calibration.md).
                const double phi = std::atan2(sn, cn);
                const double r = std::hypot(sn, cn);
                const double a = phi - corr_->offset_rad - (corr_->table.empty() ? corr_->harmonic_value(phi) : corr_->table_value(phi));
                sn = r * std::sin(a);
                cn = r * std::cos(a);
            }
            // Off the recursion: the ratiometric normalisation depends on the input only.
            const double m2 = sn * sn + cn * cn;
            const double inv_mag = m2 > 0 ? 1.0 / std::sqrt(m2) : 0.0;
            // On it: error, loop update, and the phasor rotated by the phase step.
            const double e = std::fma(sn, pc_, -cn * ps_) * inv_mag;
            inphase_ += (std::fma(sn, ps_, cn * pc_) * inv_mag - inphase_) * 0.125;
            const double post = std::fma(k1_, e, frac_);
            omega_ = std::fma(k2_, e, omega_);
            out.theta_rad[i] = post + kTwoPi * static_cast<double>(turns_);
            out.omega_rad_s[i] = omega_;
            out.valid[i] = 1;
            if (inphase_ < 0) {  // lost lock: never slip silently
                out.valid[i] = 0;
                ++lol_events_;
                ++lol_invalid_;
                lost_theta_ = out.theta_rad[i];
                lost_omega_ = omega_;
                reacquiring_ = true;
                acq_.reset(acq_n_, 1.0 / T_, cal_);
                continue;
            }
            const double step = std::fma(T_, omega_, k1_ * e);  // theta-(k+1) - theta-(k)
            frac_ += step;
            if (frac_ > kPi) { frac_ -= kTwoPi; ++turns_; }
            else if (frac_ < -kPi) { frac_ += kTwoPi; --turns_; }
            if (++since_sync_ == kResync || std::fabs(step) > 0.125) {
                // Exact phasor from the phase now and then (and for big steps, i.e. fewer
                // than ~50 samples per cycle), so rotation rounding never accumulates.
                sincos_small(frac_, ps_, pc_);
                since_sync_ = 0;
            } else {
                // sin/cos of a small step, Taylor to step^9 / step^10 (|step| <= 1/8:
                // truncation < 3e-18) by Estrin's scheme, then a complex multiply.
                const double z = step * step, z2 = z * z;
                const double ss = step * std::fma(std::fma(1.0 / 362880.0, z2, std::fma(-1.0 / 5040.0, z, 1.0 / 120.0)), z2,
                                                  std::fma(-1.0 / 6.0, z, 1.0));
                const double cs = std::fma(std::fma(std::fma(-1.0 / 3628800.0, z, 1.0 / 40320.0), z2, std::fma(-1.0 / 720.0, z, 1.0 / 24.0)),
                                           z2, std::fma(-0.5, z, 1.0));
                const double npc = std::fma(pc_, cs, -ps_ * ss);
                ps_ = std::fma(ps_, cs, pc_ * ss);
                pc_ = npc;
            }
        }
    }
    std::optional<TrackingPrior> prior() const override { return TrackingPrior{Kinematics::CV, fn_}; }
    nlohmann::json state() const override {
        return {{"calibration", cal_.to_json()}, {"k1", k1_}, {"k2_rad_s", k2_},
                {"loss_of_lock", {{"events", lol_events_}, {"samples_invalid", lol_invalid_}}}};
    }

private:
    double T_ = 1, fn_ = 100, k1_ = 0, k2_ = 0;
    Calibration cal_;
    std::unique_ptr<Correction> corr_;
    Acquisition acq_;
    double frac_ = 0, omega_ = 0;  // predicted phase in (-pi, pi] (+ turns), rate
    double pc_ = 1, ps_ = 0;       // cos, sin of the predicted phase
    long long turns_ = 0;
    static constexpr int kResync = 256;
    int since_sync_ = 0;
    // lock detector
    std::size_t acq_n_ = 200;
    double inphase_ = 1.0, lost_theta_ = 0, lost_omega_ = 0;
    bool reacquiring_ = false;
    long long lol_events_ = 0, lol_invalid_ = 0;
    Calibration::Coeffs k_{0, 0, 1, 1, 0, 1};  // cal_'s constants, read per sample
};

}  // namespace

void register_tracking_loop(std::vector<EstimatorInfo>& r) {
    r.push_back({"pll2", "Ratiometric type-II tracking loop (docs/model.md), natural frequency and damping as parameters",
                 Pll2::params(), [] { return std::make_unique<Pll2>(); }});
    r.back().traits.assumes_ideal_sinusoids = true;
}

}  // namespace fringe::est
