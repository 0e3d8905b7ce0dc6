// The EKF estimators behind the registry: ekf-ideal, ekf-diffraction, ekf-sin-only (Fig. 10),
// ekf-parallel (Fig. 11), ekf-rectified (Figs 12-13), ekf-selfcal and closed-loop (Fig. 9).
#include "common.hpp"
#include "ekf.hpp"
#include "registry_parts.hpp"

#include "signal_gen/optics.hpp"
#include "signal_gen/quantizer.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace fringe::est {

namespace {

using Kind = ChannelModel::Kind;
enum class Variant { TwoChannel, SinOnly, Parallel, Rectified, ClosedLoop };

struct Flavor {
    Variant variant = Variant::TwoChannel;
    std::optional<Kind> model;  // fixed, or chosen by the "model" parameter
    bool selfcal = false;
};

std::vector<ParamInfo> ekf_params(const Flavor& f) {
    std::vector<ParamInfo> p;
    p.push_back({"natural_freq_hz", "Hz", ParamType::Number, 100.0, 1e-3, 1e7, {},
                 "tracking natural frequency fn; sets q = wn^4*r*T (CV) or wn^6*r*T (CA), r the per-sample phase variance (docs/model.md, Bounds)"});
    p.push_back({"kinematics", "", ParamType::Choice, "cv", -kInf, kInf, {"cv", "ca"},
                 "cv: [theta, omega], white acceleration; ca: [theta, omega, alpha], white jerk"});
    if (!f.model) p.push_back({"model", "", ParamType::Choice, "diffraction", -kInf, kInf, {"diffraction", "ideal"},
                               "measurement model: the paper's diffraction model, or the ideal sine"});
    const bool diff = !f.model || *f.model == Kind::Diffraction;
    const bool ideal = !f.model || *f.model == Kind::Ideal;
    if (diff) {
        p.push_back({"kappa", "", ParamType::Number, nullptr, 0.05, 20, {}, "diffraction shape parameter; default: the profile's nominal kappa"});
        p.push_back({"aperture_w_rad", "rad", ParamType::Number, nullptr, 1e-3, 6.2, {}, "detector aperture w; default: the profile's"});
        p.push_back({"vmax_v", "V", ParamType::Number, nullptr, 1e-6, 100, {}, "source/detector scale Vmax; default: the profile's"});
        p.push_back({"gain", "", ParamType::Number, 1.0, 0.1, 10, {}, "fixed gain factor on the raw detector voltage (when agc is off)"});
    }
    if (ideal) for (auto& c : calibration_params()) p.push_back(c);
    p.push_back({"sigma_v", "V", ParamType::Number, nullptr, 0, 10, {}, "additive noise per channel; default: the profile's noise.sigma_add_v (1e-3 V without a profile); floored at 1e-6 V"});
    p.push_back({"sigma_gain", "", ParamType::Number, nullptr, 0, 1, {}, "relative gain noise eta1; default: the profile's noise.sigma_gain"});
    p.push_back({"adc_step_v", "V", ParamType::Number, nullptr, 0, 10, {}, "ADC step q (adds q^2/12); default: from the profile's ADC"});
    if (!f.selfcal) {
        p.push_back({"agc", "", ParamType::Boolean, false, -kInf, kInf, {}, "gain state g (AGC, Fig. 14)"});
        if (diff) p.push_back({"track_kappa", "", ParamType::Boolean, false, -kInf, kInf, {}, "kappa state (gap run-out); diffraction model only"});
        p.push_back({"track_offsets", "", ParamType::Boolean, false, -kInf, kInf, {}, "offset states o_s, o_c (the paper's DSP bias algorithm)"});
    }
    p.push_back({"q_gain_per_s", "1/s", ParamType::Number, 1e-3, 0, 10, {}, "random-walk intensity of the gain state"});
    if (diff) p.push_back({"q_kappa_per_s", "1/s", ParamType::Number, 1e-3, 0, 10, {}, "random-walk intensity of the kappa state"});
    p.push_back({"q_offset_v2_per_s", "V^2/s", ParamType::Number, 1e-6, 0, 10, {}, "random-walk intensity of the offset states"});
    if (f.selfcal) {
        p.push_back({"q_eps_per_s", "1/s", ParamType::Number, 1e-6, 0, 10, {}, "random-walk intensity of the gain-mismatch state"});
        p.push_back({"q_delta_rad2_per_s", "rad^2/s", ParamType::Number, 1e-6, 0, 10, {}, "random-walk intensity of the quadrature-error state"});
    }
    p.push_back({"calibration_gate_rad", "rad", ParamType::Number, 1e-3, 0, 1, {},
                 "with two calibration states or more (gain, kappa, offsets, gain mismatch, quadrature error): they learn only once "
                 "the phase has gone once round the figure, and while it moves at least this far (and 10 per-sample phase stds) in "
                 "256 samples; at rest or on an arc one point of the figure fits them all, and they wandered into a phase bias of "
                 "0.02-0.06 rad. Held, they are taken as known. 0 learns from every sample"});
    p.push_back(acquisition_param());
    p.push_back(LockMonitor::threshold_param());
    p.push_back({"p0_theta_rad", "rad", ParamType::Number, 0.05, 1e-9, 10, {}, "initial phase std"});
    p.push_back({"p0_omega_rad_s", "rad/s", ParamType::Number, kTwoPi * 5, 1e-9, 1e9, {}, "initial rate std"});
    if (f.variant == Variant::ClosedLoop) {
        p.push_back({"dac_bits", "bit", ParamType::Integer, 10, 1, 24, {}, "M: DAC resolution of the prediction"});
        p.push_back({"adc_bits", "bit", ParamType::Integer, 10, 1, 24, {}, "B: resolution of the ADC on the amplified error"});
        p.push_back({"gain_bits", "bit", ParamType::Integer, 6, 0, 20, {}, "N: error gain 2^N (the maximum when auto_range is on); must be below dac_bits"});
        p.push_back({"auto_range", "", ParamType::Boolean, true, -kInf, kInf, {}, "start at N = 0, raise N after ranging_samples quiet samples, lower it on saturation"});
        p.push_back({"ranging_samples", "samples", ParamType::Integer, 200, 1, 1e9, {}, "quiet samples (|error| < FS/4) before N is raised"});
        p.push_back({"range_v", "V", ParamType::Number, 1.25, 1e-3, 100, {}, "DAC and ADC full scale is [-range_v, range_v)"});
    }
    return p;
}

class EkfEstimator final : public Estimator {
public:
    explicit EkfEstimator(Flavor f) : f_(f) {}

    void reset(const EstimatorConfig& cfg) override {
        const Params p = resolve_params(ekf_params(f_), cfg.params);
        if (!(cfg.sample_rate_hz > 0)) throw ConfigError("sample_rate_hz", "must be positive");
        T_ = 1.0 / cfg.sample_rate_hz;
        const auto& enc = cfg.encoder;
        Kind kind = f_.model ? *f_.model : (p.string("model") == "ideal" ? Kind::Ideal : Kind::Diffraction);

        ChannelModel::Setup s;
        s.kind = kind;
        Calibration acq_cal;
        if (kind == Kind::Diffraction) {
            auto pick = [&](const char* key, std::optional<double> from_profile) {
                if (auto v = p.optional_number(key)) return *v;
                if (from_profile) return *from_profile;
                throw ConfigError(std::string("params.") + key,
                                  "the diffraction model needs an encoder profile (--encoder, or the capture's sidecar) or this parameter");
            };
            s.kappa = pick("kappa", enc ? std::optional(enc->kappa_nominal()) : std::nullopt);
            s.aperture_w_rad = pick("aperture_w_rad", enc ? std::optional(enc->aperture_w_rad) : std::nullopt);
            s.vmax_v = pick("vmax_v", enc ? std::optional(enc->vmax_v) : std::nullopt);
            s.reference_v = enc ? enc->reference_v() : s.vmax_v * s.aperture_w_rad / 2;
            if (enc) {
                s.gain_sin = 1 + enc->lissajous.gain_mismatch / 2;
                s.gain_cos = 1 - enc->lissajous.gain_mismatch / 2;
                s.offset_sin_v = enc->lissajous.offset_sin_v;
                s.offset_cos_v = enc->lissajous.offset_cos_v;
                s.delta_rad = enc->lissajous.quadrature_error_rad;
            }
            s.gain = p.number("gain");
            double kmax = s.kappa;
            if (enc) kmax = std::max(kmax, enc->kappa_max());
            const bool tk = !f_.selfcal && p.boolean("track_kappa");
            s.harmonics = optics::harmonic_count(tk ? 1.5 * kmax : kmax);
            if (s.harmonics > 15) throw ConfigError("params.kappa", "too large (more than 15 harmonics)");
            // Acquisition calibration: fundamental amplitude and DC after the front end.
            const double A = s.gain * s.vmax_v * optics::fundamental_amplitude(s.kappa, s.aperture_w_rad);
            const double dc = s.gain * s.vmax_v * s.aperture_w_rad / 2 - s.reference_v;
            acq_cal.offset_sin_v = s.gain_sin * dc + s.offset_sin_v;
            acq_cal.offset_cos_v = s.gain_cos * dc + s.offset_cos_v;
            acq_cal.amplitude_sin_v = s.gain_sin * A;
            acq_cal.amplitude_cos_v = s.gain_cos * A;
            acq_cal.quadrature_error_rad = s.delta_rad;
            acq_cal.prepare();
        } else {
            acq_cal = nominal_calibration(enc, p);
            s.amplitude_v = 0.5 * (acq_cal.amplitude_sin_v + acq_cal.amplitude_cos_v);
            s.gain_sin = acq_cal.amplitude_sin_v / s.amplitude_v;
            s.gain_cos = acq_cal.amplitude_cos_v / s.amplitude_v;
            s.offset_sin_v = acq_cal.offset_sin_v;
            s.offset_cos_v = acq_cal.offset_cos_v;
            s.delta_rad = acq_cal.quadrature_error_rad;
            amplitude_known_ = enc.has_value() || p.optional_number("amplitude_sin_v") || p.optional_number("amplitude_cos_v");
        }
        const double sigma = p.optional_number("sigma_v").value_or(enc ? enc->noise.sigma_add_v : 1e-3);
        s.sigma_v = std::max(sigma, 1e-6);
        s.sigma_gain = p.optional_number("sigma_gain").value_or(enc ? enc->noise.sigma_gain : 0.0);
        s.adc_step_v = p.optional_number("adc_step_v").value_or(enc && !enc->adc.ideal() ? enc->adc.step_v() : 0.0);

        closed_ = f_.variant == Variant::ClosedLoop;
        if (closed_) {
            s.adc_step_v = 0;  // the closed loop's own quantisation enters per sample
            const int M = static_cast<int>(p.integer("dac_bits")), B = static_cast<int>(p.integer("adc_bits"));
            n_max_ = static_cast<int>(p.integer("gain_bits"));
            if (n_max_ >= M) throw ConfigError("params.gain_bits", "must be below dac_bits (the DAC step amplified by 2^N must fit the ADC range)");
            const double fs_v = p.number("range_v");
            dac_ = Quantizer{M, -fs_v, fs_v};
            adc_ = Quantizer{B, -fs_v, fs_v};
            auto_range_ = p.boolean("auto_range");
            ranging_ = static_cast<std::uint64_t>(p.integer("ranging_samples"));
            quiet_limit_v_ = fs_v / 2;  // FS/4 with FS = 2*range_v
        }

        // State layout
        StateLayout L;
        const Kinematics kin = p.string("kinematics") == "ca" ? Kinematics::CA : Kinematics::CV;
        L.n = 2;
        if (kin == Kinematics::CA) L.alpha = L.n++;
        const bool agc = f_.selfcal || p.boolean("agc");
        const bool offs = f_.selfcal || p.boolean("track_offsets");
        const bool tk = kind == Kind::Diffraction && !f_.selfcal && p.boolean("track_kappa");
        if (agc) L.gain = L.n++;
        if (tk) L.kappa = L.n++;
        if (offs) { L.off_s = L.n++; L.off_c = L.n++; }
        if (f_.selfcal) { L.eps = L.n++; L.delta = L.n++; }
        model_.configure(s, L);
        layout_ = L;
        kin_ = kin;
        n_kin_ = L.alpha >= 0 ? 3 : 2;
        // One point of the figure (two voltages) determines the phase and one calibration state
        // (a gain alone: the radius), not more: the gate is for two calibration states or more.
        cal_gate_rad_ = L.n - n_kin_ >= 2 ? p.number("calibration_gate_rad") : 0.0;

        // Nominal state and initial covariance
        x0_.fill(0.0);
        p0_.fill(0.0);
        p0_[0] = std::pow(p.number("p0_theta_rad"), 2);
        p0_[1] = std::pow(p.number("p0_omega_rad_s"), 2);
        const double amp_scale = kind == Kind::Ideal ? s.amplitude_v : acq_cal.amplitude_sin_v;
        if (L.alpha >= 0) p0_[L.alpha] = std::pow(kTwoPi * 1000, 2);
        if (L.gain >= 0) { x0_[L.gain] = s.gain; p0_[L.gain] = 0.05 * 0.05; }
        if (L.kappa >= 0) { x0_[L.kappa] = s.kappa; p0_[L.kappa] = 0.05 * 0.05; }
        if (L.off_s >= 0) { x0_[L.off_s] = s.offset_sin_v; x0_[L.off_c] = s.offset_cos_v;
                            p0_[L.off_s] = p0_[L.off_c] = std::pow(0.05 * amp_scale, 2); }
        if (L.eps >= 0) p0_[L.eps] = 0.05 * 0.05;
        if (L.delta >= 0) { x0_[L.delta] = s.delta_rad; p0_[L.delta] = 0.05 * 0.05; }

        // Tuning: q from wn and the per-sample phase variance r = 1/J_bar (MODEL.md 4.3, 6)
        fn_ = p.number("natural_freq_hz");
        const double wn = kTwoPi * fn_;
        if (wn * T_ > 0.5) throw ConfigError("params.natural_freq_hz", "too high for the sample rate (wn*T must be < 0.5)");
        auto q_for = [&](int channels) {
            double extra = 0;
            if (closed_) extra = std::pow(adc_.step_v() / std::ldexp(1.0, n_max_), 2) / 12;
            // closed loop: tune for the final resolution; the information is evaluated with
            // the white term of the model plus that step.
            ChannelModel tmp = model_;
            if (closed_) { auto st = s; st.adc_step_v = std::sqrt(12 * extra); tmp.configure(st, L); }
            const double r = 1.0 / tmp.mean_information(x0_.data(), channels);
            return kin == Kinematics::CV ? std::pow(wn, 4) * r * T_ : std::pow(wn, 6) * r * T_;
        };
        Ekf::Options o;
        o.layout = L;
        o.kinematics = kin;
        o.T_s = T_;
        o.q_gain_per_s = p.number("q_gain_per_s");
        if (kind == Kind::Diffraction) o.q_kappa_per_s = p.number("q_kappa_per_s");
        o.q_offset_v2_per_s = p.number("q_offset_v2_per_s");
        if (f_.selfcal) { o.q_eps_per_s = p.number("q_eps_per_s"); o.q_delta_rad2_per_s = p.number("q_delta_rad2_per_s"); }
        channels_ = f_.variant == Variant::SinOnly ? 1 : 3;
        o.q_kin = q_for(f_.variant == Variant::Parallel ? 1 : channels_);
        filter_.configure(o, &model_);
        if (f_.variant == Variant::Parallel) {
            o.q_kin = q_for(2);
            filter_c_.configure(o, &model_);
        }
        r_model_ = 1.0 / model_.mean_information(x0_.data(), channels_);
        cal_gate_eff_rad_ = std::max(cal_gate_rad_, 10.0 * std::sqrt(r_model_));

        acq_cal_ = acq_cal;
        acq_n_ = static_cast<std::size_t>(p.integer("acquisition_samples"));
        fs_ = cfg.sample_rate_hz;
        acq_.reset(acq_n_, fs_, acq_cal);
        lock_.reset(acq_cal, p.number("lock_threshold_rad"));
        selfcal_sum_ = 0;
        skipped_ = clipped_ = nonfinite_ = 0;
        cal_held_ = 0;
        skip_run_ = 0;
        reacquiring_ = false;
        n_gain_ = auto_range_ ? 0 : n_max_;
        quiet_ = 0;
        first_max_gain_sample_ = -1;
        k_ = 0;
    }

    void process(InputSpan in, OutputSpan out) override {
        const std::size_t n = in.size();
        lock_.prepare(in.sin_v.data(), in.cos_v.data(), n);
        for (std::size_t i = 0; i < n; ++i, ++k_) {
            double z[2] = {in.sin_v[i], in.cos_v[i]};
            const bool finite = std::isfinite(z[0]) && std::isfinite(z[1]);
            const double ref_rad = finite ? lock_.reference_at(i, z[0], z[1]) : 0.0;
            if (!acq_.done()) {
                if (closed_) { z[0] = adc_.apply(z[0]); z[1] = adc_.apply(z[1]); }  // N = 0, DAC at 0
                if (!finite) { z[0] = z[1] = 0; ++nonfinite_; }
                const bool done = acq_.add(z[0], z[1]);
                selfcal_sum_ += z[0] * z[0] + z[1] * z[1];
                out.theta_rad[i] = lock_.anchor(acq_.last_atan2_rad());
                out.omega_rad_s[i] = 0;
                out.valid[i] = 0;
                if (reacquiring_) lock_.count_invalid();
                if (done) start();
                continue;
            }
            filter_.predict();
            if (f_.variant == Variant::Parallel) filter_c_.predict();
            if (!finite) {
                ++nonfinite_;
                emit(out, i, 0);
                continue;
            }
            if (cal_gate_rad_ > 0) {
                // The calibration states learn only while the phase moves, and only once it has
                // covered the whole figure: at rest one point of the figure fits any offset and
                // gain, an arc of it hardly better, and learning from them drifted the phase by
                // 0.02-0.06 rad (standstill, 0.02 and 0.2 Hz). Moving: the phase has moved a
                // gate within the last kCalRest samples. The phase is the loss-of-lock
                // reference's (the signal's own atan2, which does not move when the calibration
                // does; the filter's phase did, and opened the gate at rest); the gate at least
                // 10 of its per-sample stds, so noise does not open it. Held, the calibration
                // is taken as known: the tracker runs as if told it.
                if (finite) {
                    if (std::isnan(cal_anchor_rad_)) cal_anchor_rad_ = cal_lo_rad_ = cal_hi_rad_ = ref_rad;
                    cal_lo_rad_ = std::min(cal_lo_rad_, ref_rad);
                    cal_hi_rad_ = std::max(cal_hi_rad_, ref_rad);
                    if (std::fabs(ref_rad - cal_anchor_rad_) >= cal_gate_eff_rad_) {
                        cal_anchor_rad_ = ref_rad;
                        cal_moving_until_ = k_ + kCalRest;
                    }
                }
                const bool learn = k_ < cal_moving_until_ && cal_hi_rad_ - cal_lo_rad_ >= kTwoPi;
                if (!learn) ++cal_held_;
                if (learn && !cal_learning_) {
                    // The phase was tracked with the calibration taken as known: its covariance
                    // says nothing of the calibration's error, and learning from it was ~100x
                    // slower (5 Hz). It reopens to its initial value.
                    filter_.reopen(n_kin_, p0_.data());
                    if (f_.variant == Variant::Parallel) filter_c_.reopen(n_kin_, p0_.data());
                }
                cal_learning_ = learn;
                filter_.hold_states_from(learn ? kMaxStates : n_kin_);
                if (f_.variant == Variant::Parallel) filter_c_.hold_states_from(learn ? kMaxStates : n_kin_);
            }
            bool ok = true;
            switch (f_.variant) {
                case Variant::TwoChannel: ok = filter_.update(z, 3, nullptr, 0.0); break;
                case Variant::SinOnly: ok = filter_.update(z, 1, nullptr, 0.0); break;
                case Variant::Parallel:
                    ok = filter_.update(z, 1, nullptr, 0.0);
                    ok = filter_c_.update(z, 2, nullptr, 0.0) && ok;
                    break;
                case Variant::Rectified: {
                    // Z1/Z2 fold of the offset-free samples (Figs 12-13): Z1 = the channel
                    // nearer its zero crossing, Z2 the other, both made non-negative.
                    const double ds = z[0] - acq_cal_.offset_sin_v, dc = z[1] - acq_cal_.offset_cos_v;
                    const double ss = ds < 0 ? -1.0 : 1.0, sc = dc < 0 ? -1.0 : 1.0;
                    double fold[4];
                    if (std::fabs(ds) * acq_cal_.amplitude_cos_v <= std::fabs(dc) * acq_cal_.amplitude_sin_v) {
                        fold[0] = ss; fold[1] = 0; fold[2] = 0; fold[3] = sc;
                    } else {
                        fold[0] = 0; fold[1] = sc; fold[2] = ss; fold[3] = 0;
                    }
                    ok = filter_.update(z, 3, fold, 0.0);
                    break;
                }
                case Variant::ClosedLoop: ok = closed_loop_update(z); break;
            }
            if (!ok) {
                // not taken in (an outlier, or a singular update): no measured output. A run of
                // them is a signal the filter no longer fits (its amplitude jumped): a loss of
                // lock, acquired afresh, not a coast that looks valid
                ++skipped_;
                emit(out, i, 0);
                if (++skip_run_ >= kSkipRun) {
                    skip_run_ = 0;
                    lock_.declare_loss();
                    lose_lock(out, i);
                }
                continue;
            }
            skip_run_ = 0;
            emit(out, i, 1);
            if (!lock_.check(out.theta_rad[i])) lose_lock(out, i);
        }
    }

    BoundClass bound_class() const override { return BoundClass::Tracker; }
    std::optional<TrackingPrior> prior() const override { return TrackingPrior{kin_, fn_}; }
    nlohmann::json state() const override {
        nlohmann::json j{{"states", layout_.n}, {"r_model_rad2", r_model_}, {"skipped_updates", skipped_},
                         {"nonfinite_samples", nonfinite_}, {"loss_of_lock", lock_.to_json()}};
        if (acq_.done()) {
            auto put = [&](const char* key, int idx) { if (idx >= 0) j[key] = filter_.state(idx); };
            put("gain", layout_.gain);
            put("kappa", layout_.kappa);
            put("offset_sin_v", layout_.off_s);
            put("offset_cos_v", layout_.off_c);
            put("gain_mismatch", layout_.eps);
            put("quadrature_error_rad", layout_.delta);
            if (cal_gate_rad_ > 0) j["calibration_held_samples"] = cal_held_;
            double min_eig = 0;
            bool ok = filter_.covariance_ok(&min_eig);
            if (f_.variant == Variant::Parallel) {
                double m2 = 0;
                ok = filter_c_.covariance_ok(&m2) && ok;
                min_eig = std::min(min_eig, m2);
            }
            j["covariance_ok"] = ok;  // symmetric and Cholesky-factorable
            j["covariance_min_eigenvalue"] = min_eig;
        }
        if (closed_) {
            j["gain_bits_final"] = n_gain_;
            j["clipped_samples"] = clipped_;
            j["first_sample_at_max_gain"] = first_max_gain_sample_;
        }
        return j;
    }

private:
    // Loss of lock (LockMonitor): this sample is invalid, and the filter restarts from a
    // fresh acquisition (its calibration states back at their initial values), anchored to
    // the reference's turn count: a safe mode instead of a slip.
    void lose_lock(OutputSpan out, std::size_t i) {
        out.valid[i] = 0;
        lock_.count_invalid();
        acq_.reset(acq_n_, fs_, acq_cal_);
        selfcal_sum_ = 0;
        reacquiring_ = true;
        if (closed_) { n_gain_ = auto_range_ ? 0 : n_max_; quiet_ = 0; }
    }

    void start() {
        auto x = x0_;
        x[0] = lock_.anchor(acq_.theta_rad());
        lock_.rearm();
        reacquiring_ = false;
        x[1] = acq_.omega_rad_s();
        if (f_.selfcal && !amplitude_known_) {
            // Unknown amplitude: the Lissajous radius over the acquisition window.
            const double rms = std::sqrt(selfcal_sum_ / static_cast<double>(acq_.samples()));
            x[layout_.gain] = rms / model_.setup().amplitude_v;
        }
        filter_.init(x.data(), p0_.data());
        if (f_.variant == Variant::Parallel) filter_c_.init(x.data(), p0_.data());
        cal_anchor_rad_ = std::numeric_limits<double>::quiet_NaN();
        cal_moving_until_ = 0;
        cal_learning_ = true;
    }

    void emit(OutputSpan out, std::size_t i, std::uint8_t valid) {
        if (f_.variant == Variant::Parallel) {
            // Inverse-variance blend of the sin and cos trackers (section 3).
            const double ps = filter_.cov(0, 0), pc = filter_c_.cov(0, 0);
            const double ts = filter_.theta_rad(), tc = filter_c_.theta_rad();
            out.theta_rad[i] = ts + wrap_pi(tc - ts) * ps / (ps + pc);
            const double ws = filter_.cov(1, 1), wc = filter_c_.cov(1, 1);
            out.omega_rad_s[i] = (filter_.omega_rad_s() * wc + filter_c_.omega_rad_s() * ws) / (ws + wc);
        } else {
            out.theta_rad[i] = filter_.theta_rad();
            out.omega_rad_s[i] = filter_.omega_rad_s();
        }
        out.valid[i] = valid;
    }

    // Fig. 9: DAC(prediction), analog error times 2^N, B-bit ADC, z = DAC + ADC/2^N.
    bool closed_loop_update(const double v[2]) {
        double h[2];
        filter_.predict_measurement(h);
        const double gain = std::ldexp(1.0, n_gain_);
        double z[2];
        bool clipped = false, quiet = true;
        for (int ch = 0; ch < 2; ++ch) {
            const double y_dac = dac_.apply(h[ch]);
            const double amp = (v[ch] - y_dac) * gain;
            clipped |= adc_.clips(amp);
            quiet &= std::fabs(amp) < quiet_limit_v_;
            z[ch] = y_dac + adc_.apply(amp) / gain;
        }
        if (clipped) {
            ++clipped_;
            if (auto_range_ && n_gain_ > 0) --n_gain_;
            quiet_ = 0;
            return true;  // skip the update for a clipped sample
        }
        const double step = adc_.step_v() / gain;
        const bool ok = filter_.update(z, 3, nullptr, step * step / 12);
        if (auto_range_ && n_gain_ < n_max_) {
            quiet_ = quiet ? quiet_ + 1 : 0;
            if (quiet_ >= ranging_) { ++n_gain_; quiet_ = 0; }
        }
        if (n_gain_ == n_max_ && first_max_gain_sample_ < 0) first_max_gain_sample_ = static_cast<long long>(k_);
        return ok;
    }

    Flavor f_;
    double T_ = 1, fn_ = 100, r_model_ = 0;
    Kinematics kin_ = Kinematics::CV;
    StateLayout layout_;
    ChannelModel model_;
    Ekf filter_, filter_c_;
    int channels_ = 3;
    std::array<double, kMaxStates> x0_{}, p0_{};
    Calibration acq_cal_;
    Acquisition acq_;
    LockMonitor lock_;
    std::size_t acq_n_ = 200;
    double fs_ = 1;
    bool reacquiring_ = false;
    bool amplitude_known_ = true;
    double selfcal_sum_ = 0;
    int n_kin_ = 2;               // kinematic states (theta, omega[, alpha]); calibration states follow
    double cal_gate_rad_ = 0;     // calibration_gate_rad (0: fewer than two calibration states, or no gate)
    double cal_anchor_rad_ = 0;   // the reference phase where it last moved a gate (NaN: none yet)
    double cal_lo_rad_ = 0, cal_hi_rad_ = 0;  // the reference phase's range since the filter started
    double cal_gate_eff_rad_ = 0; // the gate used: calibration_gate_rad, at least 10 per-sample phase stds
    std::uint64_t cal_held_ = 0;  // samples whose calibration update was held (state "calibration_held_samples")
    std::uint64_t cal_moving_until_ = 0;  // the phase counts as moving before this sample (k_)
    bool cal_learning_ = true;  // the calibration states learnt from the last sample
    static constexpr std::uint64_t kCalRest = 256;  // no gate of phase travel in this many samples: at rest
    long long skipped_ = 0, clipped_ = 0, nonfinite_ = 0, first_max_gain_sample_ = -1;
    static constexpr int kSkipRun = 32;  // updates not taken in a row that make a loss of lock
    int skip_run_ = 0;
    std::uint64_t k_ = 0;
    // closed loop
    bool closed_ = false, auto_range_ = true;
    Quantizer dac_, adc_;
    int n_max_ = 0, n_gain_ = 0;
    std::uint64_t ranging_ = 200, quiet_ = 0;
    double quiet_limit_v_ = 0.625;
};

void add(std::vector<EstimatorInfo>& r, const std::string& name, const std::string& summary, Flavor f) {
    r.push_back({name, summary, ekf_params(f), [f] { return std::make_unique<EkfEstimator>(f); }});
    r.back().traits.told_amplitude = true;
}

}  // namespace

void register_ekf(std::vector<EstimatorInfo>& r) {
    add(r, "ekf-ideal", "EKF with the ideal-sine measurement model (Zimmerman-style), CV or CA; optional gain and offset states",
        {Variant::TwoChannel, Kind::Ideal, false});
    r.back().traits.assumes_ideal_sinusoids = true;
    add(r, "ekf-diffraction", "EKF with the paper's diffraction measurement model (kappa, w, Vmax), CV or CA, Joseph form; optional gain (AGC), kappa (gap) and offset states",
        {Variant::TwoChannel, Kind::Diffraction, false});
    add(r, "ekf-sin-only", "EKF on the sin channel alone (Fig. 10): coasts through the sin extrema where the channel carries no phase information",
        {Variant::SinOnly, std::nullopt, false});
    add(r, "ekf-parallel", "Separate sin-only and cos-only EKFs blended by inverse variance (Fig. 11)",
        {Variant::Parallel, std::nullopt, false});
    add(r, "ekf-rectified", "EKF on the rectified pair Z1 = min(|s|,|c|), Z2 = max(|s|,|c|) (Figs 12-13), in its two-channel form",
        {Variant::Rectified, std::nullopt, false});
    add(r, "ekf-selfcal",
        "Self-calibrating EKF: ideal-sine model with gain, offset, gain-mismatch and quadrature-error states; needs no distortion parameters. Use it when the encoder's Lissajous errors are unknown and its waveform is close to sinusoidal",
        {Variant::TwoChannel, Kind::Ideal, true});
    r.back().traits.told_amplitude = false;  // its gain states start from the data
    add(r, "closed-loop", "Closed-loop converter of Fig. 9 simulated from the analog input: M-bit DAC of the EKF prediction, error amplified by 2^N, B-bit ADC, auto-ranging of N",
        {Variant::ClosedLoop, std::nullopt, false});
}

}  // namespace fringe::est
