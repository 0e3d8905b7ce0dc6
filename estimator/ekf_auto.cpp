// ekf-auto (issue 13): an estimator told nothing. A phase tracker whose measurement model is a
// Fourier shape table per channel plus one learnt direction of variation, learnt by a slower
// least-squares identifier against a fixed-lag smoothed phase. docs/estimators.md ("ekf-auto: design") gives the reasons.
//
//   shape:    z_ch = h0_ch(theta) + u * h1_ch(theta) + noise,
//             h_ch(theta) = c_ch . phi(theta), phi = [1, cos theta, sin theta, ..., cos M theta, sin M theta]
//             h0 is the shape (offsets, gains, quadrature, harmonics); h1 (order <= 4) is the
//             direction in which the shape varies and u (dimensionless, |h1| = |h0|) how far:
//             a light source that drifts (h1 = the raw signal with its DC pedestal) or a gap
//             that swings once per revolution (the diffraction shape is affine in 1/kappa) is
//             exactly one such direction. h1 starts as h0 (a common gain) and is learnt.
//             v (dimensionless) scales the fundamental of h0 alone (g below): z = h0 + u h1 + v g.
//             It follows what one learnt direction cannot: a gap whose kappa dips just below 1
//             stops the 2nd harmonic at 0 (c2 = max(0, 1 - 1/kappa)) while the fundamental goes
//             on changing, a kink in the variation. v is not learnt (the identifier learns the
//             samples as they are); it starts once h1 is learnt, with a small random walk
//             (q_fundamental_per_s) and a 0.2 s pull to 0, so it only carries brief departures.
//   tracker:  EKF on [theta, omega, alpha, u, v]: CA kinematics (white jerk, q = wn^6 r T with r
//             from the learnt shape and the measured noise; constant speed, acceleration,
//             reversals and standstill without a CV/CA choice), u a random walk (q_variation_per_s,
//             raised up to 30x from the variation u showed over the memory, from the third replay on)
//             with a slow pull to 0. The bandwidth wn adapts to the motion (adapt()): from the
//             mean square jerk the tracker's own acceleration shows, the wn that minimises noise
//             (2 wn r T) plus lag ((j/wn^3)^2), never below natural_freq_hz (issue 28);
//             a two-channel update with R the residual covariance it measures.
//   learning phase: the tracker follows any shape error that varies slower than fn, so a warped
//             shape and a warped phase could agree. The identifier therefore learns against
//             the tracker's phase averaged over the samples whose phase spans one cycle,
//             centred on the sample (a fixed lag of one cycle): the average of a periodic warp
//             over its period is zero, the average of the motion is its centre value plus
//             alpha T^2 (N^2 - 1)/24 (odd terms cancel), alpha from the mean speeds of the
//             one-cycle windows either side of the centre (both warp-free too).
//   identifier: weighted least squares of z_ch on [phi(theta), (u - u_mean) phi_1(theta)], each point
//             weighted by the phase it advanced (every part of the cycle weighs the same at any
//             speed; a standstill adds nothing, so the shape holds still and cannot drift),
//             forgetting over memory_cycles of phase. The Gram matrix is kept as trig sums
//             sum w u^p e^{ik theta}, so a point costs O(M). h1 has a ridge prior towards the
//             common gain (h1 = h0), so it moves only when u varies measurably, and learns
//             only from points where the tracker's lag to a jerk (jerk/wn^3) is below 1e-4 rad.
//             Each point (an average over a bin of samples) has its bias h'' var/2 taken out.
//   convention (docs/model.md): theta is defined by the fundamental of the sin channel of the
//             shape at the memory's mean variation (h0 + ubar h1; h0 itself when u does not vary).
//             After each solve its phase phi1 is moved into the tracker and all sums are rotated.
//   order:    the highest harmonic of h0 or u h1 above 4 standard errors (max_order at most), at least 1.
//   stages:   acquisition (atan2 line fit, output invalid) -> bootstrap (order 1, until the
//             identifier has seen bootstrap_cycles electrical cycles; output valid from its
//             first solve) -> full order -> h1 learnt once the shape has settled or replayed.
//   replay:   at 2, 3, 4.5, 6.75, 10.1 and 15.2 cycles seen at full order, the tracker and the
//             identifier run again over the samples since acquisition (at most 2^16) with the
//             shape learnt so far: the shape is revised, the outputs already given are not (replay()).
//   guard:    the LockMonitor of common.hpp; on loss of lock the shape is discarded and the
//             tracker re-acquires (safe mode), output invalid meanwhile.
#include "common.hpp"
#include "registry_parts.hpp"

#include "signal_gen/generator.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <complex>
#include <limits>
#include <cstring>
#include <vector>

namespace fringe::est {

namespace {

constexpr int kMaxOrder = 12;
constexpr int kMaxBasis = 2 * kMaxOrder + 1;
constexpr int kVarOrder = 4;                  // order of the variation direction h1
constexpr int kVarBasis = 2 * kVarOrder + 1;
constexpr int kTrig = 2 * kMaxOrder + 1;      // trig sums k = 0 .. 2 max_order
constexpr double kLearnMinHz = 2.0;           // no learning below this electrical rate (Hz)
constexpr double kUPullS = 5.0;               // time constant of u's pull to 0 (s)
constexpr double kVPullS = 0.2;               // time constant of v's pull to 0 (s)
constexpr double kURidge = 3e-4;              // ridge on h1: as if u had this rms
constexpr int kOutlierRun = 32;               // this many in a row: the signal changed, acquire afresh
constexpr double kOutlierRadius2 = 4.0;        // before the shape is learnt: a residual beyond 2 fundamental amplitudes is an outlier
constexpr double kHuberNis = 25.0;             // a sample's share in R is capped at this normalised innovation: a
                                               // fraction p of spikes then inflates R by 1/(1 - 25p) at most (100
                                               // let 1 % of spikes grow it without bound); Gaussian noise beyond it: 4e-6
constexpr double kMaxLagRad = 1e-3;           // rad: a point whose tracker lag (jerk/wn^3) exceeds this does not teach h1
constexpr double kCorrRef = 0.03;             // rad: a point's acceleration correction at which its weight halves
constexpr double kSettled = 1e-3;             // shape changes below this (relative) for 8 solves: settled
constexpr double kMaxPhaseVar = 0.1;          // rad^2: a shape and noise giving a worse per-sample phase is no signal
constexpr double kWarpChange = 1e-2;          // a shape change above this (relative) pauses learning
constexpr std::size_t kHistMax = 1 << 16;     // samples kept for a replay (1 MB); a longer first learning is not replayed
constexpr double kReplayFirstCycles = 2.0;    // the first replay, after this many cycles seen at full order ...
constexpr double kReplayFactor = 1.5;         // ... then at 1.5 times as many (2, 3, 4.5, 6.75, 10.1, 15.2 cycles) ...
constexpr int kReplays = 6;                   // ... this many in all
constexpr double kJerkMemoryS = 0.02;         // s: the mean square jerk's memory (the bandwidth follows it)
constexpr double kJerkNoise = 0.2;            // the jerk estimate's noise variance, in units of P22 wn^2
constexpr double kMaxWnT = 0.1;               // the adaptive bandwidth's ceiling, wn T
constexpr int kQVaryReplays = 3;              // u's random walk follows the variation seen from this replay on ...
constexpr double kQVaryGain = 10.0;           // ... at this many times var(u) over the memory's duration ...
constexpr double kQVaryMax = 30.0;            // ... at most this many times q_variation_per_s

using Coeffs = std::array<double, kMaxBasis>;
using Cx = std::complex<double>;
// the identifier's normal equations, h0 and h1 at most: on the stack (a solve every 32 points)
using GramMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxBasis + kVarBasis, kMaxBasis + kVarBasis>;
using GramVec = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxBasis + kVarBasis, 1>;

// wrap_pi with a fast path: the tracker's phase is already in (-pi, pi] (predict() wraps it),
// where std::remainder returns it unchanged. Elsewhere (a point's unwrapped phase, every few
// samples) the same number without std::remainder (3 % of the run time): x - n 2 pi is
// exactly representable (it is what remainder returns), so one fma gives it exactly, n being
// x / 2 pi rounded (the same n as remainder's but at a tie, where +pi and -pi are the same angle).
inline double wrap(double x) {
    if (x > -kPi && x <= kPi) return x;
    const double y = std::fma(-std::nearbyint(x * (1.0 / kTwoPi)), kTwoPi, x);
    return y <= -kPi ? y + kTwoPi : (y > kPi ? y - kTwoPi : y);
}

class EkfAuto final : public Estimator {
public:
    static std::vector<ParamInfo> params() {
        return {
            {"natural_freq_hz", "Hz", ParamType::Number, 100.0, 1e-3, 1e7, {},
             "tracking natural frequency fn of the CA tracker; q = wn^6*r*T with r from the learnt shape and measured noise"},
            {"adaptive_bandwidth", "", ParamType::Boolean, true, -kInf, kInf, {},
             "raise the tracker's bandwidth above natural_freq_hz where the motion's jerk needs it (chosen from the data); false: fixed at natural_freq_hz"},
            {"max_order", "", ParamType::Integer, 8, 6, kMaxOrder, {},
             "highest harmonic of the shape table the identifier fits; the tracker uses those that stand above the noise"},
            {"memory_cycles", "cycles", ParamType::Number, 16.0, 1.0, 1e6, {},
             "identifier forgetting horizon, in electrical cycles of motion (slow changes of the shape are followed by the variation state)"},
            {"points_per_cycle", "points", ParamType::Integer, 256, 8, 4096, {},
             "at most this many samples per electrical cycle enter the identifier (each weighted by the phase it advanced)"},
            {"refit_points", "points", ParamType::Integer, 32, 1, 1e6, {}, "identifier solve every this many accepted points (twice as many once it has seen memory_cycles)"},
            {"bootstrap_cycles", "cycles", ParamType::Number, 2.0, 1.0, 1e4, {},
             "electrical cycles seen with a fundamental-only shape before the full order is fitted"},
            {"noise_memory_samples", "samples", ParamType::Number, 2000.0, 10, 1e9, {},
             "time constant of the residual covariance estimate R"},
            {"q_variation_per_s", "1/s", ParamType::Number, 0.001, 0, 10, {},
             "random-walk intensity of the shape-variation state u (u is relative to the shape's amplitude); the floor: a shape seen to vary raises it, up to 30x"},
            {"q_fundamental_per_s", "1/s", ParamType::Number, 1e-6, 0, 10, {},
             "random-walk intensity of v, a brief change of the fundamental's amplitude alone (relative), on top of the learnt variation (0: off)"},
            {"start_from_profile", "", ParamType::Boolean, false, -kInf, kInf, {},
             "start from the told encoder profile's exact shape (by default a profile that comes with the capture or scenario is ignored: told nothing)"},
            {"learn", "", ParamType::Boolean, true, -kInf, kInf, {},
             "learn the shape from the samples; false needs start_from_profile and a profile, and tracks with its exact shape (an oracle for tests)"},
            acquisition_param(),
            LockMonitor::threshold_param(),
        };
    }

    void reset(const EstimatorConfig& cfg) override {
        const Params p = resolve_params(params(), cfg.params);
        if (!(cfg.sample_rate_hz > 0)) throw ConfigError("sample_rate_hz", "must be positive");
        fs_ = cfg.sample_rate_hz;
        T_ = 1.0 / fs_;
        jerk_a_ = T_ / kJerkMemoryS;
        fn_ = p.number("natural_freq_hz");
        // the default 100 Hz needs fs >= 1.26 kHz; below, a default (not a given value) becomes fs/(8 pi)
        if (!cfg.params.contains("natural_freq_hz") && kTwoPi * fn_ / fs_ > 0.25) fn_ = fs_ / (4 * kTwoPi);
        wn_ = kTwoPi * fn_;
        wn_floor_ = wn_;
        adaptive_ = p.boolean("adaptive_bandwidth");
        n_in_ = 0;
        stats_n_ = 0;
        stats_wn_ = 0;
        wn_peak_ = wn_;
        shape_at_ = -1;
        vary_at_ = -1;
        if (wn_ * T_ > 0.5) throw ConfigError("params.natural_freq_hz", "too high for the sample rate (wn*T must be < 0.5)");
        max_order_ = static_cast<int>(p.integer("max_order"));
        ppc_ = static_cast<int>(p.integer("points_per_cycle"));
        gate_ = kTwoPi / ppc_;
        memory_rad_ = kTwoPi * p.number("memory_cycles");
        refit_ = static_cast<long long>(p.integer("refit_points"));
        bootstrap_rad_ = kTwoPi * p.number("bootstrap_cycles");
        noise_a_ = 1.0 / p.number("noise_memory_samples");
        q_u_ = p.number("q_variation_per_s");
        q_v_ = p.number("q_fundamental_per_s");
        learn_ = p.boolean("learn");
        acq_n_ = static_cast<std::size_t>(p.integer("acquisition_samples"));
        told_ = false;
        if (p.boolean("start_from_profile")) {
            if (!cfg.encoder) throw ConfigError("params.start_from_profile", "true needs an encoder profile (--encoder, or the capture's)");
            profile_shape(*cfg.encoder);
            told_ = true;
        }
        if (!learn_ && !told_) throw ConfigError("params.learn", "false needs start_from_profile: true and an encoder profile to take the shape from");
        // delay line for the cycle-centred average: two cycles at kLearnMinHz must fit, in at
        // most 2^17 samples (96 bytes each, 12.6 MB); above fs = 131 kHz learning starts at
        // fs/2^16 Hz electrical rather than at kLearnMinHz
        const double need = 2 * fs_ / kLearnMinHz + 4;
        cap_ = std::bit_ceil(static_cast<std::size_t>(std::min(need, double(1 << 17))));
        ring_.assign(cap_, Slot{});
        Calibration none;
        none.prepare();
        cal_ = none;
        lock_.reset(none, p.number("lock_threshold_rad"));
        nonfinite_ = 0;
        no_evidence_ = 0;
        outliers_ = 0;
        outlier_run_ = 0;
        signal_changes_ = 0;
        refits_ = 0;
        restart();
    }

    void process(InputSpan in, OutputSpan out) override {
        const std::size_t n = in.size();
        lock_.prepare(in.sin_v.data(), in.cos_v.data(), n);
        for (std::size_t i = 0; i < n; ++i) {
            const double zs = in.sin_v[i], zc = in.cos_v[i];
            ++n_in_;
            if (!(std::isfinite(zs) && std::isfinite(zc))) {
                ++nonfinite_;
                if (acq_.done()) predict();
                out.theta_rad[i] = theta_out();
                out.omega_rad_s[i] = x_[1];
                out.valid[i] = 0;
                seg0_ = k_;  // the delay line restarts after a gap
                hist_ok_ = false;
                continue;
            }
            lock_.reference_at(i, zs, zc);
            if (!acq_.done()) {
                // an outlier to the reference (a 1e300, a spike off the phase) stays out of the
                // line fit and the amplitude
                const bool skip = lock_.outlier();
                if (!skip) acq_sum_ += zs * zs + zc * zc;
                const bool done = skip ? acq_.skip() : acq_.add(zs, zc);
                out.theta_rad[i] = lock_.anchor(acq_.last_atan2_rad());
                out.omega_rad_s[i] = 0;
                out.valid[i] = 0;
                if (reacquiring_) lock_.count_invalid();
                if (done) start();
                continue;
            }
            predict();
            if (!update(zs, zc)) {
                // an outlier (a glitch, a spike): not used, its output invalid. The delay line
                // keeps going with the model's own prediction in its place (restarting it, as
                // after a gap, left a capture with a glitch every cycle never learnt). A run of
                // them is a signal that changed (its amplitude jumped): acquire it afresh.
                ++outliers_;
                hist_ok_ = false;  // the history is replayed only when every sample in it was used
                out.theta_rad[i] = theta_out();
                out.omega_rad_s[i] = x_[1];
                out.valid[i] = 0;
                if (++outlier_run_ >= kOutlierRun) {
                    ++signal_changes_;
                    restart();
                    reacquiring_ = true;
                } else if (learn_) {
                    push(pred_s_, pred_c_);
                    learn();
                }
                continue;
            }
            outlier_run_ = 0;
            out.theta_rad[i] = theta_out();
            out.omega_rad_s[i] = x_[1];
            // no valid output before the shape was learnt from motion (or told): a capture that
            // never moves, or holds no signal, gives no phase; nor where the learnt shape leaves
            // a per-sample phase std above 0.3 rad
            const bool evidence = (told_ || refits_since_start_ > 0) && r_bar_ < kMaxPhaseVar;
            out.valid[i] = evidence ? 1 : 0;
            if (!evidence) ++no_evidence_;
            if (!lock_.check(out.theta_rad[i])) {
                out.valid[i] = 0;
                lock_.count_invalid();
                restart();
                reacquiring_ = true;
                continue;
            }
            if (learn_) {
                if (hist_ok_) {
                    if (hist_.size() < kHistMax) hist_.push_back({zs, zc});
                    else hist_ok_ = false;
                }
                push(zs, zc);
                learn();
                if (replay_due_) replay();
            }
        }
    }

    BoundClass bound_class() const override { return BoundClass::Tracker; }
    std::optional<TrackingPrior> prior() const override { return TrackingPrior{Kinematics::CA, fn_}; }

    nlohmann::json state() const override {
        nlohmann::json j{{"stage", !acq_.done() ? "acquisition" : (full_ ? "tracking" : "bootstrap")},
                         {"order", order_}, {"refits", refits_}, {"accepted_points", accepted_},
                         {"learn", learn_}, {"told_profile", told_},
                         {"nonfinite_samples", nonfinite_}, {"loss_of_lock", lock_.to_json()},
                         {"samples_without_evidence", no_evidence_}, {"outlier_samples", outliers_},
                         {"signal_changes", signal_changes_}};
        if (!acq_.done())
            j["message"] = "acquiring at the end of the capture: no lock on a quadrature signal (too short, noise only, or no signal)";
        else if (refits_since_start_ == 0 && !told_ && refits_ > 0)
            j["message"] = "no valid output since it last re-acquired (the signal changed or lock was lost): the shape is learnt again from motion, and "
                           "the capture has not moved enough since, or holds no signal";
        else if (refits_since_start_ == 0 && !told_)
            j["message"] = "no valid output yet: the shape is learnt from motion (half an electrical cycle after acquisition); the capture has not moved enough, or holds no signal";
        else if (r_bar_ >= kMaxPhaseVar)
            j["message"] = "no valid output: the learnt shape and noise leave a per-sample phase std above 0.3 rad (no signal)";
        auto coeffs = [&](const Coeffs& c, int order) {
            nlohmann::json h = nlohmann::json::array();
            for (int m = 1; m <= order; ++m) h.push_back({{"order", m}, {"cos_v", c[2 * m - 1]}, {"sin_v", c[2 * m]}});
            return nlohmann::json{{"dc_v", c[0]}, {"harmonics", h}};
        };
        j["shape_sin"] = coeffs(c0s_, order_);
        j["shape_cos"] = coeffs(c0c_, order_);
        j["variation"] = {{"u", x_[3]}, {"v", x_[4]}, {"learnt", vary_}, {"q_per_s", q_ueff_}, {"sin", coeffs(c1s_, var_order())}, {"cos", coeffs(c1c_, var_order())}};
        j["noise_cov_v2"] = {R_[0], R_[1], R_[2]};
        // what it chose: the bandwidth now, its floor, the highest it went to and its mean
        // since acquisition; the kinematic model; when the shape (full order) and its variation
        // were learnt (s from the first sample, since the last acquisition; null: not yet)
        auto at_s = [&](long long n) { return n < 0 ? nlohmann::json(nullptr) : nlohmann::json(static_cast<double>(n) * T_); };
        j["bandwidth"] = {{"adaptive", adaptive_},
                          {"natural_freq_hz", wn_ / kTwoPi},
                          {"floor_hz", wn_floor_ / kTwoPi},
                          {"peak_hz", wn_peak_ / kTwoPi},
                          {"mean_hz", stats_n_ > 0 ? stats_wn_ / static_cast<double>(stats_n_) / kTwoPi : wn_ / kTwoPi},
                          {"jerk_rms_rad_s3", std::sqrt(std::max(j2_, 0.0))}};
        j["kinematics"] = "ca";
        j["shape_learnt_s"] = at_s(shape_at_);
        j["replays"] = replays_;
        j["variation_learnt_s"] = at_s(vary_at_);
        j["r_model_rad2"] = r_bar_;
        return j;
    }

private:
    struct Slot {
        double zs = 0, zc = 0;
        double th = 0;   // tracker phase in the fixed frame (minus rot_ at push), rad
        double om = 0;   // tracker omega, rad/s
        double u = 0;    // tracker u divided by ugain_ at push
        double pre = 0;  // prefix sum of (th - base_)
        double upre = 0; // prefix sum of u
        double wbar = 0; // mean speed over the one-cycle window ending here (rad/s), 0: none
        double wc = 0;   // centre of that window (samples, exact: it spans 2 pi from a fractional start)
        double al = 0;   // acceleration (rad/s^2) estimated for the point whose window ends here, NaN: none
        double alt = 0;  // the time it applies to (samples)
        std::size_t wj = 0;  // that window is (wj, here]
    };

    double theta_out() const { return x_[0] + kTwoPi * static_cast<double>(turns_); }
    int var_order() const { return std::min(order_, kVarOrder); }

    // The told profile's noise-free shape (front end and Lissajous errors included, no noise,
    // drift or ADC): a DFT over one cycle of Generator::clean_channels at the nominal kappa.
    void profile_shape(const EncoderProfile& enc) {
        MotionProfile m;
        m.kind = MotionKind::Constant;
        Generator g(enc, m, 1000.0, 0);
        constexpr int kN = 512;
        const double kappa = enc.kappa_nominal();
        std::array<std::vector<Cx>, 2> X;
        X[0].assign(max_order_ + 1, 0.0);
        X[1].assign(max_order_ + 1, 0.0);
        for (int k = 0; k < kN; ++k) {
            const double th = kTwoPi * k / kN;
            double s, c;
            g.clean_channels(th, kappa, s, c);
            for (int mm = 0; mm <= max_order_; ++mm) {
                const Cx e = std::polar(1.0, -mm * th);
                X[0][mm] += s * e;
                X[1][mm] += c * e;
            }
        }
        told_s_.fill(0.0);
        told_c_.fill(0.0);
        for (int ch = 0; ch < 2; ++ch) {
            Coeffs& c = ch == 0 ? told_s_ : told_c_;
            c[0] = X[ch][0].real() / kN;
            for (int mm = 1; mm <= max_order_; ++mm) {
                c[2 * mm - 1] = 2 * X[ch][mm].real() / kN;   // cos
                c[2 * mm] = -2 * X[ch][mm].imag() / kN;      // sin
            }
        }
        told_order_ = 1;
        for (int mm = 2; mm <= max_order_; ++mm)
            if (std::hypot(told_s_[2 * mm - 1], told_s_[2 * mm]) > 1e-9 || std::hypot(told_c_[2 * mm - 1], told_c_[2 * mm]) > 1e-9)
                told_order_ = mm;
    }

    // Back to acquisition with a fundamental-only shape: the safe mode.
    void restart() {
        acq_.reset(acq_n_, fs_, cal_);
        acq_sum_ = 0;
        clear_sums();
        c0s_.fill(0.0);
        c0c_.fill(0.0);
        c1s_.fill(0.0);
        c1c_.fill(0.0);
        order_ = 1;
        full_ = false;
        refits_since_start_ = 0;
        vary_ = false;
        settled_solves_ = 0;
        accepted_ = 0;
        seen_rad_ = 0;
        have_last_ = false;
        reacquiring_ = false;
        seg0_ = k_;
        clean_after_ = 0;
        bin_.fill(0.0);
        bin_n_ = 0;
        rot_ = 0;
        ugain_ = 1;
        shape_at_ = -1;
        vary_at_ = -1;
    }

    void clear_sums() {
        for (auto& t : trig_) t.fill(Cx(0.0));
        for (auto& ch : data_)
            for (auto& d : ch) d.fill(Cx(0.0));
        scale_ = 1;
        npts_ = 0;
    }

    void start() {
        if (told_) {
            c0s_ = told_s_;
            c0c_ = told_c_;
            order_ = told_order_;
            full_ = true;
        } else {
            // fundamental-only shape of the Lissajous radius over the acquisition window
            const double amp = std::sqrt(acq_sum_ / static_cast<double>(std::max<std::size_t>(acq_.used(), 1)));
            c0s_.fill(0.0);
            c0c_.fill(0.0);
            c0s_[2] = amp;  // sin theta
            c0c_[1] = amp;  // cos theta
        }
        // the variation direction starts as a common gain
        c1s_.fill(0.0);
        c1c_.fill(0.0);
        for (int i = 0; i < kVarBasis; ++i) { c1s_[i] = c0s_[i]; c1c_[i] = c0c_[i]; }
        const double amp = std::sqrt(0.5 * (sq(c0s_[1]) + sq(c0s_[2]) + sq(c0c_[1]) + sq(c0c_[2])));
        // conservative noise until residuals are measured: 1 % of the amplitude
        const double v = sq(0.01 * std::max(amp, 1e-9));
        R_ = {v, 0.0, v};
        Rraw_ = R_;
        noise_inv();
        update_prior();
        const double th = lock_.anchor(acq_.theta_rad());
        const double fr = wrap_pi(th);
        turns_ = std::llround((th - fr) / kTwoPi);
        x_ = {fr, acq_.omega_rad_s(), 0.0, 0.0, 0.0};
        wn_ = wn_floor_;
        ema_f_ = ema_s_ = 0;
        j2_ = 0;
        since_q_ = 0;
        set_q();
        std::memset(P_, 0, sizeof P_);
        P_[0][0] = 0.05 * 0.05;
        P_[1][1] = sq(kTwoPi * 5);
        P_[2][2] = sq(kTwoPi * 1000);
        P_[3][3] = sq(0.01);
        P_[4][4] = 0;
        q_ueff_ = q_u_;
        lock_.rearm();
        reacquiring_ = false;
        // the tracker as it starts: a replay of the samples since starts from it
        snap_x_ = x_;
        std::memcpy(snap_P_, P_, sizeof P_);
        snap_turns_ = turns_;
        snap_rot_ = rot_;
        hist_.clear();
        hist_ok_ = !told_;
        replay_due_ = false;
        replays_ = 0;
        next_replay_rad_ = kReplayFirstCycles * kTwoPi;
    }

    // Re-use the samples seen since acquisition: the tracker and the identifier run over them
    // again from the start, with the shape learnt so far (causal: the outputs already given
    // stay as they were; the shape and the tracker's state now are revised). The first pass
    // learnt each point against a tracker whose shape (and so whose warp) was still changing, and
    // forgot those points quickly (a memory of a quarter of what it had seen); the replay
    // learns every point against a nearly right shape, with a memory of all of it. Done when
    // the identifier has seen 2 electrical cycles at full order, then each time 1.5x as many, up
    // to ~16 (issue 28: the shape within ~10 cycles, not ~50). Every 1.5x rather than 2x: a
    // variation the first cycles show only in part (a drifting light source) is learnt against
    // a revised direction sooner (light drift +-4 % at 1.5 Hz from 0.1 s: 8.4x -> 1.55x the
    // oracle; the 2x schedule's third replay came at 0.105 s, and 0.07-0.1 s carried 2e-3 rad).
    void replay() {
        replay_due_ = false;
        if (!hist_ok_ || replaying_) return;
        replaying_ = true;
        ++replays_;
        std::vector<std::array<double, 2>> h;
        h.swap(hist_);
        clear_sums();
        seen_rad_ = 0;
        accepted_ = 0;
        have_last_ = false;
        bin_.fill(0.0);
        bin_n_ = 0;
        seg0_ = k_;
        clean_after_ = 0;
        x_ = snap_x_;
        x_[0] += rot_ - snap_rot_;  // the snapshot's phase in today's convention
        std::memcpy(P_, snap_P_, sizeof P_);
        turns_ = snap_turns_;
        if (x_[0] > kPi || x_[0] < -kPi) {
            const double k = std::round(x_[0] / kTwoPi);
            x_[0] -= kTwoPi * k;
            turns_ += static_cast<long long>(k);
        }
        snap_x_ = x_;
        snap_turns_ = turns_;
        snap_rot_ = rot_;
        wn_ = wn_floor_;
        ema_f_ = ema_s_ = 0;
        j2_ = 0;
        set_q();
        for (const auto& z : h) {
            predict();
            if (!update(z[0], z[1])) push(pred_s_, pred_c_);
            else push(z[0], z[1]);
            learn();
        }
        if (seen_rad_ >= bootstrap_rad_) solve();  // the replay's one solve
        hist_.swap(h);
        replaying_ = false;
        next_replay_rad_ = kReplayFactor * seen_rad_;
    }

    static double sq(double v) { return v * v; }

    void noise_inv() {
        const double det = R_[0] * R_[2] - R_[1] * R_[1];
        const double d = det > 0 ? det : R_[0] * R_[2];
        Ri_ = {R_[2] / d, -R_[1] / d, R_[0] / d};
    }

    // Mean phase information J_bar over a cycle from the shape and R; q = wn^6 r T (CA), r = 1/J_bar.
    // J(theta) = h0'(theta)' R^-1 h0'(theta); its mean over a cycle by Parseval, from the
    // harmonics (harmonic m of h0' is m times that of h0, turned a quarter cycle):
    // J_bar = sum_m m^2/2 [Ri00 (a_s^2 + b_s^2) + 2 Ri01 (a_s a_c + b_s b_c) + Ri11 (a_c^2 + b_c^2)]
    // (the mean over a 64-point grid, as it was, to rounding: 2 order < 64)
    void update_prior() {
        double jbar = 0;
        for (int m = 1; m <= order_; ++m) {
            const double as = c0s_[2 * m - 1], bs = c0s_[2 * m], ac = c0c_[2 * m - 1], bc = c0c_[2 * m];
            jbar += 0.5 * m * m * ((as * as + bs * bs) * Ri_[0] + 2 * (as * ac + bs * bc) * Ri_[1] + (ac * ac + bc * bc) * Ri_[2]);
        }
        r_bar_ = jbar > 0 ? 1.0 / jbar : 1.0;
        set_q();
    }

    // The bandwidth the motion needs. A CA tracker with q = wn^6 r T has a phase variance of
    // about 2 wn r T from the noise and lags a jerk j by j/wn^3: the sum is least at
    // wn^7 = 3 j^2 / (r T). j^2 is the mean square of the jerk, measured from the tracker's own
    // acceleration (the slope between two of its running means, less their noise); the bandwidth
    // never falls below natural_freq_hz (the floor: no jerk measured) nor rises above fs/(10 pi).
    void adapt() {
        // the two running means of alpha, time constants tf = 3/wn and ts = 3 tf (s); their
        // rates T/tf, T/ts and 1/(ts - tf) are set with wn_ (set_q())
        ema_f_ += ema_af_ * (x_[2] - ema_f_);
        ema_s_ += ema_as_ * (x_[2] - ema_s_);
        const double j = (ema_f_ - ema_s_) * ema_inv_;      // rad/s^3: a ramp of alpha lags them by j tf and j ts
        j2_ += jerk_a_ * (j * j - j2_);
        if (++since_q_ < 16) return;
        since_q_ = 0;
        // the noise in j: alpha's error (P22, correlated over 1/wn) through the two means
        const double noise = kJerkNoise * P_[2][2] * wn_ * wn_;
        const double sig = std::max(j2_ - noise, 0.0);
        double w = wn_floor_;
        if (sig > 0 && r_bar_ > 0) w = std::max(w, std::pow(3 * sig / (r_bar_ * T_), 1.0 / 7));
        w = std::min(w, kMaxWnT / T_);
        // a change in wn of less than 2 % is not worth a new Q
        if (std::fabs(w - wn_) > 0.02 * wn_) {
            wn_ = w;
            set_q();
        }
        wn_peak_ = std::max(wn_peak_, wn_);
        stats_wn_ += wn_;
        ++stats_n_;
    }

    void set_q() {
        const double tf = 3.0 / wn_, ts = 3 * tf;
        ema_af_ = T_ / tf;
        ema_as_ = T_ / ts;
        ema_inv_ = 1.0 / (ts - tf);
        const double q = std::pow(wn_, 6) * r_bar_ * T_;
        const double T = T_;
        Q_[0][0] = q * std::pow(T, 5) / 20; Q_[0][1] = Q_[1][0] = q * std::pow(T, 4) / 8;
        Q_[0][2] = Q_[2][0] = q * std::pow(T, 3) / 6; Q_[1][1] = q * std::pow(T, 3) / 3;
        Q_[1][2] = Q_[2][1] = q * T * T / 2; Q_[2][2] = q * T;
    }

    // h0 and h1 of both channels and their derivatives in theta (h0 at order_, h1 at var_order()).
    void eval(double theta, double h[2], double d[2], double h1[2], double d1[2]) const {
        double g[2], dg[2];
        eval(theta, h, d, h1, d1, g, dg);
    }
    // ... and g, the fundamental of h0 (the direction of v), with its derivative.
    void eval(double theta, double h[2], double d[2], double h1[2], double d1[2], double g[2], double dg[2]) const {
        double s1, c1;
        sincos_small(wrap(theta), s1, c1);
        g[0] = c0s_[1] * c1 + c0s_[2] * s1;
        g[1] = c0c_[1] * c1 + c0c_[2] * s1;
        dg[0] = c0s_[2] * c1 - c0s_[1] * s1;
        dg[1] = c0c_[2] * c1 - c0c_[1] * s1;
        double hs = c0s_[0], hc = c0c_[0], ds = 0, dc = 0;
        double gs = c1s_[0], gc = c1c_[0], es = 0, ec = 0;
        double cm = c1, sm = s1;
        const int mv = var_order();
        for (int m = 1; m <= order_; ++m) {
            const double as = c0s_[2 * m - 1], bs = c0s_[2 * m], ac = c0c_[2 * m - 1], bc = c0c_[2 * m];
            hs += as * cm + bs * sm;
            hc += ac * cm + bc * sm;
            ds += m * (bs * cm - as * sm);
            dc += m * (bc * cm - ac * sm);
            if (m <= mv) {
                const double as1 = c1s_[2 * m - 1], bs1 = c1s_[2 * m], ac1 = c1c_[2 * m - 1], bc1 = c1c_[2 * m];
                gs += as1 * cm + bs1 * sm;
                gc += ac1 * cm + bc1 * sm;
                es += m * (bs1 * cm - as1 * sm);
                ec += m * (bc1 * cm - ac1 * sm);
            }
            const double cn = cm * c1 - sm * s1;
            sm = sm * c1 + cm * s1;
            cm = cn;
        }
        h[0] = hs; h[1] = hc; d[0] = ds; d[1] = dc;
        h1[0] = gs; h1[1] = gc; d1[0] = es; d1[1] = ec;
    }

    // d^2/dtheta^2 of h0 + u h1, both channels (V/rad^2).
    void second_derivative(double theta, double u, double out[2]) const {
        double s1, c1;
        sincos_small(wrap(theta), s1, c1);
        double cm = c1, sm = s1, vs = 0, vc = 0;
        const int mv = var_order();
        for (int m = 1; m <= order_; ++m) {
            double as = c0s_[2 * m - 1], bs = c0s_[2 * m], ac = c0c_[2 * m - 1], bc = c0c_[2 * m];
            if (m <= mv) {
                as += u * c1s_[2 * m - 1]; bs += u * c1s_[2 * m];
                ac += u * c1c_[2 * m - 1]; bc += u * c1c_[2 * m];
            }
            const double m2 = static_cast<double>(m * m);
            vs -= m2 * (as * cm + bs * sm);
            vc -= m2 * (ac * cm + bc * sm);
            const double cn = cm * c1 - sm * s1;
            sm = sm * c1 + cm * s1;
            cm = cn;
        }
        out[0] = vs;
        out[1] = vc;
    }

    void predict() {
        const double T = T_;
        x_[0] += T * x_[1] + 0.5 * T * T * x_[2];
        x_[1] += T * x_[2];
        const double pull = 1.0 - T / kUPullS;
        x_[3] *= pull;
        const double vpull = 1.0 - T / kVPullS;
        x_[4] *= vpull;
        if (x_[0] > kPi || x_[0] < -kPi) {
            const double k = std::round(x_[0] / kTwoPi);
            x_[0] -= kTwoPi * k;
            turns_ += static_cast<long long>(k);
        }
        // P = F P F' + Q, F = [[1, T, T^2/2, 0, 0], [0, 1, T, 0, 0], [0, 0, 1, 0, 0], [0, 0, 0, pull, 0], [0, 0, 0, 0, pull]]
        const double h2 = 0.5 * T * T;
        double FP[kNx][kNx];
        for (int j = 0; j < kNx; ++j) {
            FP[0][j] = P_[0][j] + T * P_[1][j] + h2 * P_[2][j];
            FP[1][j] = P_[1][j] + T * P_[2][j];
            FP[2][j] = P_[2][j];
            FP[3][j] = pull * P_[3][j];
            FP[4][j] = vpull * P_[4][j];
        }
        for (int i = 0; i < kNx; ++i) {
            P_[i][0] = FP[i][0] + T * FP[i][1] + h2 * FP[i][2];
            P_[i][1] = FP[i][1] + T * FP[i][2];
            P_[i][2] = FP[i][2];
            P_[i][3] = pull * FP[i][3];
            P_[i][4] = vpull * FP[i][4];
        }
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) P_[i][j] += Q_[i][j];
        P_[3][3] += q_ueff_ * T;
        if (vary_) P_[4][4] += q_v_ * T;  // v only once the variation direction is learnt
    }

    // false: the sample is an outlier (its innovation beyond kOutlierNis), nothing updated
    bool update(double zs, double zc) {
        double h[2], d[2], h1[2], d1[2], g[2], dg[2];
        eval(x_[0], h, d, h1, d1, g, dg);
        const double u = x_[3], v = x_[4];
        pred_s_ = h[0] + u * h1[0] + v * g[0];
        pred_c_ = h[1] + u * h1[1] + v * g[1];
        const double rs = zs - pred_s_, rc = zc - pred_c_;
        // H = [[a0, 0, 0, b0, g0], [a1, 0, 0, b1, g1]]: phase, u and v columns only
        const double a0 = d[0] + u * d1[0] + v * dg[0], a1 = d[1] + u * d1[1] + v * dg[1], b0 = h1[0], b1 = h1[1];
        double PH[kNx][2];
        for (int i = 0; i < kNx; ++i) {
            PH[i][0] = P_[i][0] * a0 + P_[i][3] * b0 + P_[i][4] * g[0];
            PH[i][1] = P_[i][0] * a1 + P_[i][3] * b1 + P_[i][4] * g[1];
        }
        const double HPH00 = a0 * PH[0][0] + b0 * PH[3][0] + g[0] * PH[4][0], HPH01 = a0 * PH[0][1] + b0 * PH[3][1] + g[0] * PH[4][1],
                     HPH11 = a1 * PH[0][1] + b1 * PH[3][1] + g[1] * PH[4][1];
        // An outlier? Before the shape is learnt the residuals are the shape's, up to about half
        // the amplitude on a 10 % duty-cycle signal: only a residual beyond two fundamental
        // amplitudes is one (a 5 V glitch on a 1 V signal; learnt into R and the shape it made
        // every later glitch look normal: 0.1 % of them gave 200x the error). Once learnt, a
        // normalised innovation beyond kOutlierNis is one.
        const double amp2 = 0.5 * (c0s_[1] * c0s_[1] + c0s_[2] * c0s_[2] + c0c_[1] * c0c_[1] + c0c_[2] * c0c_[2]);
        if (rs * rs + rc * rc > kOutlierRadius2 * amp2) return false;
        double w = 1.0;  // the sample's weight in R: a rare large residual below the gate must not inflate it
        if (full_ && refits_since_start_ > 0) {
            const double T00 = HPH00 + R_[0], T01 = HPH01 + R_[1], T11 = HPH11 + R_[2];
            const double dt = T00 * T11 - T01 * T01;
            if (dt > 0) {
                // nis = num / dt; compared as num against dt (no division per sample)
                const double num = T11 * rs * rs - 2 * T01 * rs * rc + T00 * rc * rc;
                if (num > kOutlierNis * dt) return false;
                if (num > kHuberNis * dt) w = kHuberNis * dt / num;
            }
        }
        // the noise covariance R: the a priori residuals' covariance less the state's part H P H'
        R_[0] += noise_a_ * (w * rs * rs - HPH00 - R_[0]);
        R_[1] += noise_a_ * (w * rs * rc - HPH01 - R_[1]);
        R_[2] += noise_a_ * (w * rc * rc - HPH11 - R_[2]);
        Rraw_[0] += noise_a_ * (w * rs * rs - Rraw_[0]);
        Rraw_[2] += noise_a_ * (w * rc * rc - Rraw_[2]);
        // a covariance: each variance at least a quarter of the raw residuals' (the filter's own
        // P can overstate its error), 1e-12 of the shape's power and 1e-24 V^2; correlation
        // below 0.999
        const double floor = std::max(1e-12 * (c0s_[1] * c0s_[1] + c0s_[2] * c0s_[2] + c0c_[1] * c0c_[1] + c0c_[2] * c0c_[2]), 1e-24);
        R_[0] = std::max({R_[0], 0.25 * Rraw_[0], floor});
        R_[2] = std::max({R_[2], 0.25 * Rraw_[2], floor});
        if (R_[1] * R_[1] > 0.998001 * (R_[0] * R_[2])) {  // 0.999^2: the square root only when it binds
            const double rmax = 0.999 * std::sqrt(R_[0] * R_[2]);
            R_[1] = std::clamp(R_[1], -rmax, rmax);
        }
        if (++since_noise_ == 256) {  // R and q together, so the tracker's bandwidth stays fn
            since_noise_ = 0;
            noise_inv();
            update_prior();
        }
        const double S00 = HPH00 + R_[0], S01 = HPH01 + R_[1], S11 = HPH11 + R_[2];
        const double det = S00 * S11 - S01 * S01;
        if (!(det > 0)) return true;
        const double idet = 1.0 / det;
        const double i00 = S11 * idet, i01 = -S01 * idet, i11 = S00 * idet;
        double K[kNx][2];
        for (int i = 0; i < kNx; ++i) {
            K[i][0] = PH[i][0] * i00 + PH[i][1] * i01;
            K[i][1] = PH[i][0] * i01 + PH[i][1] * i11;
        }
        for (int i = 0; i < kNx; ++i) x_[i] += K[i][0] * rs + K[i][1] * rc;
        // P -= K (H P) = K PH'
        for (int i = 0; i < kNx; ++i)
            for (int j = i; j < kNx; ++j) {
                const double pij = P_[i][j] - (K[i][0] * PH[j][0] + K[i][1] * PH[j][1]);
                P_[i][j] = P_[j][i] = pij;
            }
        // a variation larger than the shape itself is not a variation: hold it
        if (std::fabs(x_[3]) > 0.5) x_[3] = std::copysign(0.5, x_[3]);
        if (std::fabs(x_[4]) > 0.5) x_[4] = std::copysign(0.5, x_[4]);
        if (adaptive_) adapt();
        return true;
    }

    // --- the delay line and the cycle-centred phase ---

    Slot& slot(std::size_t idx) { return ring_[idx & (cap_ - 1)]; }
    std::size_t live_start() const { return std::max({seg0_, k_ > cap_ ? k_ - cap_ : std::size_t{0}, rebase_floor_}); }

    void push(double zs, double zc) {
        Slot& s = slot(k_);
        s.zs = zs;
        s.zc = zc;
        s.th = theta_out() - rot_;
        s.om = x_[1];
        s.u = x_[3] / ugain_;
        s.wbar = 0;
        s.al = std::numeric_limits<double>::quiet_NaN();
        if (k_ == seg0_) {
            base_ = s.th;
            s.pre = s.th - base_;
            s.upre = s.u;
        } else {
            const Slot& prev = slot(k_ - 1);
            s.pre = prev.pre + (s.th - base_);
            s.upre = prev.upre + s.u;
        }
        ++k_;
        if (((k_ - seg0_) & (cap_ / 4 - 1)) == 0) rebase();  // cap_ is a power of 2
    }

    // Prefix sums relative to a nearer base, so they stay small (exact re-summation). Only the
    // slots a window can still reach are re-summed: 8 of the last window's length (a point
    // reaches back 2.5 windows; a motion that slows by more than 3x before the next rebase
    // pauses learning until its windows fit), and the older ones leave the live range. (All of
    // the ring, 2^17 slots of 96 bytes each 2^15 samples, was 8 % of the run time.)
    void rebase() {
        base_ = slot(k_ - 1).th;
        std::size_t from = live_start();
        if (last_window_ > 0) from = std::max(from, k_ - std::min(k_, 8 * last_window_ + 1024));
        rebase_floor_ = from;
        double acc = 0, uacc = 0;
        for (std::size_t j = from; j < k_; ++j) {
            Slot& s = slot(j);
            acc += s.th - base_;
            uacc += s.u;
            s.pre = acc;
            s.upre = uacc;
        }
    }

    // The point learnt at each sample: the sample half a cycle back, with the tracker's phase
    // averaged over the samples (j, k] whose phase spans one cycle. The window is found in the
    // tracker's own phase: theta_hat = theta + warp(theta) with a periodic warp spans 2 pi exactly
    // when theta does, so the warp averages out whatever its size (a window sized from the
    // tracker's speed would not: its speed carries the warp's derivative).
    void learn() {
        const std::size_t k = k_ - 1;
        if (std::fabs(x_[1]) < kTwoPi * kLearnMinHz || (x_[1] > 0) != (slot(k - 1).om > 0)) {
            moving_since_ = k;  // no window reaches back over a standstill or a reversal
            return pause();
        }
        const std::size_t lo = std::max(live_start(), moving_since_);
        if (k < lo + 2) return pause();
        const double thk = slot(k).th;
        if (wstart_ < lo) wstart_ = lo;
        while (wstart_ + 1 < k && std::fabs(thk - slot(wstart_ + 1).th) >= kTwoPi) ++wstart_;
        while (wstart_ > lo && std::fabs(thk - slot(wstart_).th) < kTwoPi) --wstart_;
        const std::size_t j = wstart_;
        if (std::fabs(thk - slot(j).th) < kTwoPi) return pause();  // not a cycle yet (or a reversal in it)
        const std::size_t N = k - j;
        last_window_ = N;
        // the window's exact length: where the phase crossed 2 pi between samples j and j + 1
        const double dj = std::fabs(thk - slot(j).th), dj1 = std::fabs(thk - slot(j + 1).th);
        const double frac = dj > dj1 ? std::clamp((dj - kTwoPi) / (dj - dj1), 0.0, 1.0) : 0.0;
        const double Nf = static_cast<double>(N) - frac;
        // mean speed over exactly one cycle (the warp cancels: the phase advanced 2 pi) and the
        // acceleration from the mean speeds of this window and the one a window earlier
        const double om_k = std::copysign(kTwoPi, thk - slot(j).th) / (Nf * T_);
        slot(k).wbar = om_k;
        slot(k).wj = j;
        slot(k).wc = static_cast<double>(k) - 0.5 * Nf;
        // The point: the centre of the one-cycle window ending half a cycle back (at e, centre
        // m = k - N). Its acceleration comes from the mean speeds of the windows centred half a
        // cycle either side of m (ending at k and at k - N), so it is centred on m too.
        const auto Nr = static_cast<std::size_t>(std::llround(Nf));
        const std::size_t e = k - Nr / 2, kp = k - Nr;
        if (kp < lo || slot(kp).wbar == 0 || (slot(kp).wbar > 0) != (om_k > 0) || slot(e).wbar == 0) return pause();
        const std::size_t je = slot(e).wj;
        if (je < lo || je >= e) return pause();
        const double om = slot(e).wbar;
        // The acceleration at the point, from the mean speeds of the windows ending at k and at
        // kp, placed at their exact centres (at low speed with acceleration the two windows
        // differ in length by 10-20 %, and the correction alpha T^2 (N^2 - 1)/24 below reaches
        // 0.05 rad: taking their spacing as one window put 4e-3 rad of error into each point).
        // The slope is alpha at their midpoint; the jerk (from the previous point's estimate)
        // moves it to the point.
        const double tmid = 0.5 * static_cast<double>(je + 1 + e);     // centre of the window, samples
        const double wcA = slot(k).wc, wcB = slot(kp).wc;
        if (!(wcA - wcB > 0)) return pause();
        const double al_mid = (om_k - slot(kp).wbar) / ((wcA - wcB) * T_);
        const double mid = 0.5 * (wcA + wcB);
        const std::size_t ep = e >= Nr ? e - Nr : 0;
        double jerk = std::numeric_limits<double>::quiet_NaN();  // rad/s^3
        if (ep >= lo && std::isfinite(slot(ep).al) && mid - slot(ep).alt > 0.25 * Nf)
            jerk = (al_mid - slot(ep).al) / ((mid - slot(ep).alt) * T_);
        slot(e).al = al_mid;
        slot(e).alt = mid;
        // (the mean speeds' own jerk terms W^2/24 are left in: for smooth motion they cancel
        // the slope's snap term, which is of the same size; taking out only the first made
        // alpha 2x worse on a sine motion, in simulation and in the tracker)
        const double al = std::isfinite(jerk) ? al_mid + jerk * (tmid - mid) * T_ : al_mid;
        // no reversal or standstill inside: the tracker's own speed at both ends and in the middle
        // agrees with the window's mean speed to within a factor of 2
        // (om/2 < om_i < 2 om for om > 0, the other way round for om < 0: no division)
        const double lo_om = om > 0 ? 0.5 * om : 2.0 * om, hi_om = om > 0 ? 2.0 * om : 0.5 * om;
        for (const std::size_t i : {kp, je, e, k})
            if (!(slot(i).om > lo_om && slot(i).om < hi_om)) return pause();
        if (k_ < clean_after_) return pause();
        const std::size_t Ne = e - je;
        const double Nd = static_cast<double>(Ne);
        // the speed must not change much across the window (near a reversal the average is no
        // longer the centre's phase)
        if (Nd * T_ * std::fabs(al) > 0.25 * std::fabs(om)) return pause();
        const std::size_t c = je + 1 + (Ne - 1) / 2;                   // centre sample
        const double iNd = 1.0 / Nd;
        const double mean = (slot(e).pre - slot(je).pre) * iNd + base_;
        const double th = mean - al * T_ * T_ * (Nd * Nd - 1) / 24 + om * T_ * (static_cast<double>(c) - tmid) + rot_;
        const Slot& sc = slot(c);
        // the samples between two points are averaged into one, so at many samples per cycle
        // every sample counts. The average of a shape over a spread of phases is
        // h(mean) + h''(mean) var/2 (harmonic m shrinks by m^2 var/2, 2.9e-5 for the fundamental
        // at 256 points per cycle): that bias is taken out with the current shape when the point
        // is made. Left in, the learnt shape was too small (the tracker's u and the identifier
        // amplified it to 1.8e-4), a gain error that u, whose direction can carry a DC pedestal
        // (light drift), turns into an offset and so a first-harmonic phase error.
        // u is averaged over the same cycle: the tracker's u follows each sample's noise (and,
        // while the shape is still wrong, its warp); as a regressor it must not carry the noise
        // of the sample it explains
        double u = (slot(e).upre - slot(je).upre) * iNd * ugain_;
        // The tracker lags a jerk by about jerk/wn^3, and that lag is in the averaged phase too
        // (it is no periodic warp); u swings with it (at reversals, +-1e-2) while the samples do
        // not vary, and h1 fitted to that is a direction of errors. Where the lag exceeds
        // kMaxLagRad the point teaches h0 but not h1: its u is the memory's mean. A jerk not
        // known yet (no previous point's acceleration) does not hold a point back, and the
        // limit is 1e-3 rad, not 1e-4: in the first cycles the jerk estimate is the noise of
        // the tracker's early accelerations, and 1e-4 held back half of the first replay's points
        // (84 % before it) with their u at the mean; a drifting light source's gain, so
        // flattened, taught a wrong direction h1 (its cos fundamental near 0), the tracker then
        // erred by up to 0.1 rad, learning paused and the later replays came late (+-8 % at 2 Hz
        // at 80 Hz electrical, 0.6 s from 0.1 s: 470x the oracle -> 2.8x; +-7 % at 2.5 Hz at
        // 103 Hz: 71x -> 1.7x, this change alone). The reversals' lag, 5e-3 rad, is still held back.
        if (std::fabs(jerk) >= kMaxLagRad * (wn_ * wn_ * wn_)) {  // lag = |jerk|/wn^3 (NaN: not known, not held back)
            const double W = trig_[0][0].real();
            u = W > 0 ? trig_[1][0].real() / W : 0.0;
        }
        if (bin_n_ == 0) bin_th0_ = th;
        bin_[0] += sc.zs; bin_[1] += sc.zc; bin_[2] += th; bin_[3] += u;
        bin_[4] += th - bin_th0_; bin_[5] += sq(th - bin_th0_);
        bin_corr_ = std::max(bin_corr_, std::fabs(al * T_ * T_ * (Nd * Nd - 1) / 24));
        ++bin_n_;
        double w = gate_;
        if (have_last_) {
            const double step = std::fabs(th - last_);
            if (step < gate_) return;
            if (step < 4 * gate_) w = step;
        }
        last_ = th;
        have_last_ = true;
        const double n = static_cast<double>(bin_n_);
        const double tm = bin_[2] / n, um = bin_[3] / n;
        const double var = std::max(bin_[5] / n - sq(bin_[4] / n), 0.0);  // rad^2
        double zs = bin_[0] / n, zc = bin_[1] / n;
        if (var > 0) {
            double h2[2];
            second_derivative(tm, um, h2);
            zs -= 0.5 * var * h2[0];
            zc -= 0.5 * var * h2[1];
        }
        // a point whose acceleration correction is large is less sure of its phase (1 % of the
        // correction, the alpha estimate's error): its weight falls as 1/(1 + (corr/kCorrRef)^2)
        accumulate(zs, zc, tm, um, w / (1 + sq(bin_corr_ / kCorrRef)));
        bin_corr_ = 0;
        bin_.fill(0.0);
        bin_n_ = 0;
    }

    // Learning paused: the next point starts afresh.
    void pause() {
        have_last_ = false;
        bin_.fill(0.0);
        bin_n_ = 0;
    }

    // --- the identifier ---

    void accumulate(double zs, double zc, double th, double u, double w) {
        // the horizon grows with what was seen (the first cycles, learnt while the shape and so
        // the tracker's warp still changed, are forgotten sooner), up to memory_cycles
        // (after a replay every point was learnt against a nearly right shape: all of it is kept)
        const double horizon = horizon_rad();
        scale_ *= std::exp(w / horizon);
        if (scale_ > 1e100) {
            for (auto& t : trig_)
                for (auto& v : t) v /= scale_;
            for (auto& ch : data_)
                for (auto& dd : ch)
                    for (auto& v : dd) v /= scale_;
            npts_ /= scale_;
            scale_ = 1;
        }
        const double ww = w * scale_;
        const int M = max_order_;
        double s1, c1;
        sincos_small(wrap(th), s1, c1);
        const Cx e1(c1, s1);
        Cx e = 1.0;
        const double wu = ww * u, wuu = wu * u;
        // the u-weighted sums are needed only as far as h1's order reaches (k <= M + 4, 8, 4)
        const int k1 = std::min(2 * M, M + kVarOrder), k2 = 2 * kVarOrder;
        const double wzs = ww * zs, wzc = ww * zc, wuzs = wu * zs, wuzc = wu * zc;
        for (int k = 0; k <= 2 * M; ++k) {
            trig_[0][k] += ww * e;
            if (k <= k1) trig_[1][k] += wu * e;
            if (k <= k2) trig_[2][k] += wuu * e;
            if (k <= M) {
                data_[0][0][k] += wzs * e;
                data_[1][0][k] += wzc * e;
                if (k <= kVarOrder) {
                    data_[0][1][k] += wuzs * e;
                    data_[1][1][k] += wuzc * e;
                }
            }
            e *= e1;
        }
        npts_ += scale_;
        seen_rad_ += w;
        ++accepted_;
        // told a profile, the first solve waits for the bootstrap's cycles (a fit of the full
        // order to half a cycle would throw the exact shape away)
        // (a replay solves once, at its end: every point of it learnt against the same shape;
        // solving as it went, the shape took in a drift's first few % as it was replayed and
        // light drift stayed at 20-30x the bound from 0.1 s, 8x so)
        // (once the memory is full, every 2 refit_points: the shape then changes by its noise
        // between solves; a tenth of the run time went to the solves, the outputs' accuracy is the same)
        if (!replaying_ && accepted_ % (seen_rad_ >= memory_rad_ ? 2 * refit_ : refit_) == 0 && seen_rad_ >= (told_ ? bootstrap_rad_ : kPi)) solve();
    }

    // the identifier's forgetting horizon (rad of phase)
    double horizon_rad() const { return std::clamp((replays_ > 0 ? 1.0 : 0.25) * seen_rad_, 2 * kTwoPi, memory_rad_); }

    // Gram entry <f_a, f_b> for basis indices a, b of [1, cos, sin, cos 2, sin 2, ...] from trig sums t.
    static double gram(const std::array<Cx, kTrig>& t, int a, int b) {
        auto C = [&](int k) { return t[std::abs(k)].real(); };
        auto S = [&](int k) { return k >= 0 ? t[k].imag() : -t[-k].imag(); };
        if (a == 0 && b == 0) return C(0);
        if (a == 0 || b == 0) {
            const int i = a == 0 ? b : a;
            const int m = (i + 1) / 2;
            return (i % 2 == 1) ? C(m) : S(m);
        }
        const int m = (a + 1) / 2, n = (b + 1) / 2;
        const bool ca = a % 2 == 1, cb = b % 2 == 1;
        if (ca && cb) return 0.5 * (C(m - n) + C(m + n));
        if (!ca && !cb) return 0.5 * (C(m - n) - C(m + n));
        if (ca) return 0.5 * (S(m + n) - S(m - n));   // cos m sin n
        return 0.5 * (S(m + n) - S(n - m));            // sin m cos n
    }

    static double rhs(const std::array<Cx, kMaxOrder + 1>& d, int a) {
        if (a == 0) return d[0].real();
        const int m = (a + 1) / 2;
        return a % 2 == 1 ? d[m].real() : d[m].imag();
    }

    void solve() {
        if (!full_ && seen_rad_ >= bootstrap_rad_) full_ = true;
        const int fit_order = full_ ? max_order_ : 1;
        const int n0 = 2 * fit_order + 1;
        // the variation direction is learnt once the shape has settled: before, u follows the
        // shape's own errors and says nothing about how the shape varies
        const int n1 = vary_ ? 2 * std::min(fit_order, kVarOrder) + 1 : 0;
        const int nb = n0 + n1;
        const double W = trig_[0][0].real();
        if (!(W > 0)) return;
        // centred on u's mean over the memory, so the two blocks are not collinear when u
        // hardly varies: sum w (u - ubar)^p e^{ik theta}
        const double ubar = trig_[1][0].real() / W;
        std::array<Cx, kTrig> t1, t2;
        for (int k = 0; k < kTrig; ++k) {
            t1[k] = trig_[1][k] - ubar * trig_[0][k];
            t2[k] = trig_[2][k] - 2 * ubar * trig_[1][k] + ubar * ubar * trig_[0][k];
        }
        std::array<std::array<Cx, kMaxOrder + 1>, 2> d1;
        for (int ch = 0; ch < 2; ++ch)
            for (int k = 0; k <= kMaxOrder; ++k) d1[ch][k] = data_[ch][1][k] - ubar * data_[ch][0][k];
        GramMat G(nb, nb);
        for (int a = 0; a < n0; ++a)
            for (int b = 0; b <= a; ++b) G(a, b) = G(b, a) = gram(trig_[0], a, b);
        for (int a = 0; a < n1; ++a) {
            for (int b = 0; b < n0; ++b) G(n0 + a, b) = G(b, n0 + a) = gram(t1, a, b);
            for (int b = 0; b <= a; ++b) G(n0 + a, n0 + b) = G(n0 + b, n0 + a) = gram(t2, a, b);
        }
        // ridge on h1 towards the common gain (h1 = h0): h1 moves away from it only when u
        // varies by more than about kURidge over the memory
        const double lambda = sq(kURidge) * W;
        GramVec bs(nb), bc(nb);
        for (int a = 0; a < n0; ++a) { bs(a) = rhs(data_[0][0], a); bc(a) = rhs(data_[1][0], a); }
        for (int a = 0; a < n1; ++a) {
            bs(n0 + a) = rhs(d1[0], a) + lambda * c0s_[a];
            bc(n0 + a) = rhs(d1[1], a) + lambda * c0c_[a];
            G(n0 + a, n0 + a) += lambda;
        }
        G.diagonal().array() += 1e-12 * G.diagonal().maxCoeff();
        // Cholesky (G is positive definite: a Gram matrix with a ridge and 1e-12 of its diagonal
        // added; not, and the solve is skipped), both channels in one solve
        Eigen::LLT<GramMat> llt(G);
        if (llt.info() != Eigen::Success) return;
        Eigen::Matrix<double, Eigen::Dynamic, 2, 0, kMaxBasis + kVarBasis, 2> B(nb, 2);
        B.col(0) = bs;
        B.col(1) = bc;
        B = llt.solve(B);
        const GramVec ss = B.col(0), sc = B.col(1);
        if (!ss.allFinite() || !sc.allFinite()) return;
        Coeffs ns{}, nc{}, vs{}, vc{};
        for (int i = 0; i < n0; ++i) { ns[i] = ss(i); nc[i] = sc(i); }
        for (int i = 0; i < n1; ++i) { vs[i] = ss(n0 + i); vc[i] = sc(n0 + i); }
        // before it is learnt the direction is a common gain of the whole shape, its DC included
        // (a light source that drifts scales the pedestal too; the fundamental alone, as it
        // started, left a drift of a few % in the first 0.1-0.2 s as an offset and 4e-3 rad)
        if (n1 == 0) { vs = ns; vc = nc; }
        // phase convention: the sin channel's fundamental a1 cos + b1 sin = R sin(theta + phi1), of
        // the fit, the shape at the memory's mean variation ubar (h0 + ubar h1)
        if (!(std::hypot(ns[1], ns[2]) > 0)) return;
        const double phi1 = std::atan2(ns[1], ns[2]);
        rotate(ns, fit_order, phi1);
        rotate(nc, fit_order, phi1);
        rotate(vs, std::min(fit_order, kVarOrder), phi1);
        rotate(vc, std::min(fit_order, kVarOrder), phi1);
        // h0 = fit - ubar h1, h1 first rid of its component along the fit's derivative and of a
        // cos term in its sin fundamental (remove_phase(); again below once the order is known),
        // so that h0, h1 and the fit all have theta where the sin fundamental says. Taking off
        // ubar h1 with those in it turned h0 by ubar times h1's errors (h1 is learnt from a few %
        // of a drift in the first cycles), and h0 defined theta: as the memory slid over the
        // drift ubar moved, and theta with it, a phase bias that followed the gain (+-4 % at
        // 1.5 Hz, 0.6 s from 0.1 s: 3-4e-5 rad from 0.1 s to 0.3 s, 1.55x the oracle)
        if (n1 > 0) remove_phase(vs, vc, ns, nc, std::min(fit_order, kVarOrder));
        for (int i = 0; i < n1; ++i) { ns[i] -= ubar * vs[i]; nc[i] -= ubar * vc[i]; }
        // rotate the sums into theta' = theta + phi1: sum w u^p e^{ik theta} * e^{ik phi1}
        const Cx r1 = std::polar(1.0, phi1);
        Cx r = 1.0;
        for (int k = 0; k < kTrig; ++k, r *= r1) {
            for (auto& t : trig_) t[k] *= r;
            if (k <= kMaxOrder)
                for (auto& ch : data_)
                    for (auto& dd : ch) dd[k] *= r;
        }
        x_[0] += phi1;
        rot_ += phi1;
        last_ += phi1;
        bin_[2] += phi1 * static_cast<double>(bin_n_);
        bin_th0_ += phi1;
        // order: the highest harmonic above 4 standard errors (noise from R, points counted) in
        // h0 or in the variation u h1 at u's rms over the memory (a gap run-out can have a
        // harmonic only in h1: none at one end of its swing)
        int order = 1;
        if (full_) {
            const double n_eff = std::max(npts_ / scale_, 1.0);
            const double se = std::sqrt(2.0 * std::max(R_[0], R_[2]) / n_eff);
            const double u_rms = std::sqrt(std::max(trig_[2][0].real(), 0.0) / W);
            for (int m = 2; m <= fit_order; ++m) {
                const bool in_h0 = std::hypot(ns[2 * m - 1], ns[2 * m]) > 4 * se || std::hypot(nc[2 * m - 1], nc[2 * m]) > 4 * se;
                const bool in_h1 = m <= kVarOrder && n1 > 0 &&
                                   (u_rms * std::hypot(vs[2 * m - 1], vs[2 * m]) > 4 * se || u_rms * std::hypot(vc[2 * m - 1], vc[2 * m]) > 4 * se);
                if (in_h0 || in_h1) order = m;
            }
        }
        // h1: no component along h0' (that is a phase change, not a shape change), |h1| = |h0|
        const int mv = std::min(order, kVarOrder);
        for (int i = 2 * mv + 1; i < kMaxBasis; ++i) { vs[i] = 0; vc[i] = 0; }
        remove_phase(vs, vc, ns, nc, mv);
        double n0sq = 0, n1sq = 0;
        for (int i = 1; i < n0; ++i) n0sq += ns[i] * ns[i] + nc[i] * nc[i];
        for (int i = 0; i < 2 * mv + 1; ++i) n1sq += vs[i] * vs[i] + vc[i] * vc[i];
        if (!(n1sq > 0) || !(n0sq > 0)) return;
        const double k = std::sqrt(n0sq / n1sq);  // h1 *= k, so u /= k
        for (int i = 0; i < 2 * mv + 1; ++i) { vs[i] *= k; vc[i] *= k; }
        x_[3] /= k;
        for (int i = 0; i < kNx; ++i) { P_[3][i] /= k; P_[i][3] /= k; }
        ugain_ /= k;
        for (auto& v : trig_[1]) v /= k;
        for (auto& v : trig_[2]) v /= k * k;
        for (auto& ch : data_)
            for (auto& v : ch[1]) v /= k;
        // a shape change that moves the tracker's warp: the windows that straddle it do not
        // average a periodic warp, so learning pauses for one window
        double dsq = 0;
        for (int i = 0; i < kMaxBasis; ++i) dsq += sq(ns[i] - c0s_[i]) + sq(nc[i] - c0c_[i]);
        // (not before the first replay: it learns all of them again against a nearly right shape,
        // and pausing at every early solve held the full order back to ~7 cycles)
        if (dsq > sq(kWarpChange) * n0sq && (replays_ > 0 || !hist_ok_)) clean_after_ = k_ + last_window_ + 2;
        // (or from the first replay on, which learns against a nearly right shape; or, if the
        // shape keeps changing, after 8 cycles at full order: the change may be the variation itself)
        if (full_ && dsq < sq(kSettled) * n0sq) ++settled_solves_;
        if (full_ && (settled_solves_ >= 8 || replays_ > 0 || seen_rad_ >= bootstrap_rad_ + 8 * kTwoPi)) vary_ = true;
        c0s_ = ns;
        c0c_ = nc;
        c1s_ = vs;
        c1c_ = vc;
        order_ = order;
        if (full_ && shape_at_ < 0) shape_at_ = n_in_;
        if (vary_ && vary_at_ < 0) vary_at_ = n_in_;
        if (full_ && !replaying_ && hist_ok_ && replays_ < kReplays && seen_rad_ >= next_replay_rad_) replay_due_ = true;
        // u's random walk: q_variation_per_s (1e-3/s) suits a shape that holds still, and
        // a drifting light source moves u by up to ~2/s (+-6 % at 3 Hz), which that q follows
        // with errors the phase sees. From the third replay on (before, h1 is learnt from a few
        // cycles, and a looser u let the learning run away: +-6 % at 3 Hz up to 31x), the intensity is
        // the one that would spread u by kQVaryGain times the variance it showed over the
        // memory's duration, between q_variation_per_s and kQVaryMax times it. A shape that
        // does not vary keeps q_variation_per_s (on the accelerating ramp var(u) is 5e-9,
        // a drift's 1e-4 to 4e-3).
        q_ueff_ = q_u_;
        if (vary_ && replays_ >= kQVaryReplays && std::fabs(x_[1]) > 0 && q_u_ > 0) {
            const double ub = trig_[1][0].real() / W;
            const double var_u = std::max(trig_[2][0].real() / W - ub * ub, 0.0);
            const double memory_s = horizon_rad() / std::fabs(x_[1]);
            q_ueff_ = q_u_ * std::clamp(kQVaryGain * var_u / (memory_s * q_u_), 1.0, kQVaryMax);
        }
        noise_inv();
        update_prior();
        ++refits_;
        ++refits_since_start_;
    }

    // h1 (vs, vc) less its component along h0' (h0: ns, nc) over harmonics 1..mv, both channels,
    // and with no cos term in its sin channel's fundamental: theta is the phase of the sin
    // channel's fundamental in every model (docs/model.md), so no variation turns it (h1's sin
    // fundamental held at zero, the projection leaves that coordinate out: h1 is then orthogonal
    // to h0' all the same)
    static void remove_phase(Coeffs& vs, Coeffs& vc, const Coeffs& ns, const Coeffs& nc, int mv) {
        vs[1] = 0;
        double dot = 0, dd = 0;
        for (int m = 1; m <= mv; ++m) {
            const double ds_c = m == 1 ? 0.0 : m * ns[2 * m], ds_s = -m * ns[2 * m - 1], dc_c = m * nc[2 * m], dc_s = -m * nc[2 * m - 1];
            dot += vs[2 * m - 1] * ds_c + vs[2 * m] * ds_s + vc[2 * m - 1] * dc_c + vc[2 * m] * dc_s;
            dd += ds_c * ds_c + ds_s * ds_s + dc_c * dc_c + dc_s * dc_s;
        }
        if (dd > 0)
            for (int m = 1; m <= mv; ++m) {
                if (m > 1) vs[2 * m - 1] -= dot / dd * m * ns[2 * m];
                vs[2 * m] += dot / dd * m * ns[2 * m - 1];
                vc[2 * m - 1] -= dot / dd * m * nc[2 * m];
                vc[2 * m] += dot / dd * m * nc[2 * m - 1];
            }
    }

    static void rotate(Coeffs& c, int order, double phi) {
        for (int m = 1; m <= order; ++m) {
            const double co = std::cos(m * phi), si = std::sin(m * phi);
            const double a = c[2 * m - 1], b = c[2 * m];
            c[2 * m - 1] = co * a - si * b;
            c[2 * m] = si * a + co * b;
        }
    }

    double fs_ = 1, T_ = 1, fn_ = 100, wn_ = 0;
    // the adaptive bandwidth: wn_ is the tracker's now, wn_floor_ natural_freq_hz's
    bool adaptive_ = true;
    double wn_floor_ = 0, ema_f_ = 0, ema_s_ = 0, j2_ = 0, wn_peak_ = 0, stats_wn_ = 0;
    double ema_af_ = 0, ema_as_ = 0, ema_inv_ = 0;  // adapt()'s rates for wn_
    double jerk_a_ = 0;                             // T / kJerkMemoryS
    int since_q_ = 0;
    long long stats_n_ = 0, n_in_ = 0, shape_at_ = -1, vary_at_ = -1;
    int max_order_ = 8, ppc_ = 256, order_ = 1, told_order_ = 1;
    double q_ueff_ = 0.001;  // u's random-walk intensity in use (1/s): q_u_, raised for a shape that varies
    double gate_ = 0.1, memory_rad_ = 100, bootstrap_rad_ = 12, noise_a_ = 1e-3, r_bar_ = 0, q_u_ = 0.001, q_v_ = 1e-6;
    int since_noise_ = 0;
    long long refit_ = 32, accepted_ = 0, refits_ = 0, refits_since_start_ = 0, nonfinite_ = 0, no_evidence_ = 0;
    long long outliers_ = 0, signal_changes_ = 0;
    int outlier_run_ = 0;
    bool vary_ = false;
    int settled_solves_ = 0;
    bool full_ = false, have_last_ = false, reacquiring_ = false, learn_ = true, told_ = false;
    double last_ = 0, acq_sum_ = 0, seen_rad_ = 0;
    std::array<double, 6> bin_{};  // sums of zs, zc, theta, u, theta - theta0, (theta - theta0)^2 since the last point
    double bin_th0_ = 0;           // the bin's first theta, rad
    double bin_corr_ = 0;          // the largest acceleration correction in the bin, rad
    long long bin_n_ = 0;
    std::size_t acq_n_ = 200;
    // the samples since acquisition, replayed to refine the shape (replay())
    std::vector<std::array<double, 2>> hist_;
    std::array<double, 5> snap_x_{};
    double snap_P_[5][5] = {}, snap_rot_ = 0, next_replay_rad_ = 0;
    long long snap_turns_ = 0;
    bool hist_ok_ = false, replay_due_ = false, replaying_ = false;
    int replays_ = 0;
    Calibration cal_;
    Acquisition acq_;
    LockMonitor lock_;
    // tracker [theta, omega, alpha, u, v]
    static constexpr int kNx = 5;
    std::array<double, kNx> x_{};
    long long turns_ = 0;
    double P_[kNx][kNx] = {}, Q_[3][3] = {};
    std::array<double, 3> R_{}, Ri_{}, Rraw_{};
    double pred_s_ = 0, pred_c_ = 0;  // the last update's predicted measurement (V): an outlier's stand-in
    // shape h0, variation h1, the told profile's shape
    Coeffs c0s_{}, c0c_{}, c1s_{}, c1c_{}, told_s_{}, told_c_{};
    // delay line
    std::vector<Slot> ring_;
    std::size_t cap_ = 1, k_ = 0, seg0_ = 0, rebase_floor_ = 0, wstart_ = 0, clean_after_ = 0, last_window_ = 0, moving_since_ = 0;
    double base_ = 0, rot_ = 0, ugain_ = 1;
    // identifier sums, scaled by scale_: trig_[p][k] = sum w u^p e^{ik theta},
    // data_[ch][p][k] = sum w u^p z_ch e^{ik theta}
    std::array<std::array<Cx, kTrig>, 3> trig_{};
    std::array<std::array<std::array<Cx, kMaxOrder + 1>, 2>, 2> data_{};
    double scale_ = 1, npts_ = 0;
};

}  // namespace

void register_ekf_auto(std::vector<EstimatorInfo>& r) {
    r.push_back({"ekf-auto",
                 "Told nothing: a phase tracker whose measurement model is a Fourier shape table per channel (offsets, gains, "
                 "quadrature, harmonics) plus one learnt direction of shape variation (light drift, gap run-out), learnt by a "
                 "least-squares identifier against a cycle-centred smoothed phase; measures its own noise; guarded by a "
                 "loss-of-lock monitor",
                 EkfAuto::params(), [] { return std::make_unique<EkfAuto>(); }});
    r.back().traits.learns_over_cycles = 50;  // docs/estimators.md "ekf-auto"
    r.back().traits.told_param = "start_from_profile";
}

}  // namespace fringe::est