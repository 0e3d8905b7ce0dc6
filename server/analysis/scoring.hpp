// Scoring estimates against truth (MODEL.md 7), streamed in blocks so runs of 10^8 samples
// need bounded memory.
//
// e = theta_hat - theta_true over valid samples after the settle time, minus the whole
// multiple of 2*pi nearest the median of the first kMedianWindow scored errors (a cycle slip
// later in the run stays visible as slipped samples). All angles are electrical radians.
//
// Evidence: besides the error statistics the scorer counts what they rest on (samples after
// the settle time, scored samples, the electrical cycles they cover, the valid fraction), so
// a report can say how much was scored and a limit can refuse a verdict without evidence.
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace fringe {

struct HarmonicAmplitude {
    int order = 0;           // k: multiple of the electrical phase
    double amplitude_rad = 0;
    double phase_rad = 0;    // e_k(theta) = amplitude*cos(k*theta - phase)
};

struct ScoringOptions {
    double settle_s = 0.1;
    double lock_threshold_rad = 0.1;
    // Harmonics of the error per electrical cycle are fitted for orders 1..max_harmonic, fewer
    // when the scored samples visit too few distinct electrical angles (see harmonics_note).
    int max_harmonic = 16;
};

struct ErrorMetrics {
    std::uint64_t samples = 0;          // all samples seen
    std::uint64_t after_settle = 0;     // samples at or after the settle time
    std::uint64_t scored = 0;           // valid and after the settle time
    std::uint64_t invalid_after_settle = 0;
    double cycles_scored = 0;           // electrical cycles of truth traversed over the scored samples
    double removed_cycles = 0;          // multiple of 2*pi removed
    // The median error when it was too large for whole cycles to be removed (kMaxRemovableRad):
    // 0 when they were. The errors are then scored as they are (every sample slipped).
    double unremoved_error_rad = 0;
    double mean_rad = 0, std_rad = 0, rms_rad = 0, max_abs_rad = 0, max_dev_rad = 0;
    std::uint64_t slipped_samples = 0;  // |e| > pi after the multiple is removed
    // Harmonics 1x..Kx, empty when they could not be separated (harmonics_note says why).
    std::vector<HarmonicAmplitude> harmonics;
    std::string harmonics_note;
    int harmonics_requested = 0;        // max_harmonic asked for
    double harmonic_power_fraction = 0; // share of the error variance the fitted harmonics explain
    double broadband_rms_rad = 0;       // rms of the least-squares residual of [mean + harmonics 1..K] (rad)
    bool have_rate = false;
    double omega_error_mean_rad_s = 0, omega_error_std_rad_s = 0;
    std::uint64_t omega_nonfinite = 0;  // scored samples whose rate estimate was NaN/inf
    std::optional<double> lag_s;        // mean phase error / mean true rate (moving runs only)
    std::optional<double> lock_time_s;  // after the last sample with |wrap(e)| > lock threshold or invalid
    double mean_abs_omega_true_rad_s = 0;  // electrical, over scored samples with rate truth
    // The error's correlation time (samples): tau = S(0) / sigma^2 with S(0) its two-sided
    // spectral density at zero frequency (per sample), estimated by batch means (Bartlett):
    // tau_B = B var(batch means of B samples) / sigma^2 at the largest B with >= 32 batches
    // (>= 4 of 64 samples on short runs).
    // nullopt when fewer than 4 batches of 64 were scored. independent = scored / tau.
    std::optional<double> correlation_samples;
    std::uint64_t correlation_batch = 0;  // B used
    bool correlation_approximate = false;  // fewer than 32 batches of 64: the largest tau of the levels

    // valid share of the samples after the settle time; nullopt when there were none.
    std::optional<double> valid_fraction() const {
        if (!after_settle) return std::nullopt;
        return static_cast<double>(scored) / static_cast<double>(after_settle);
    }
};

class Scorer {
public:
    static constexpr std::size_t kMedianWindow = 65536;
    // Beyond this the whole cycles are not removed: at 1e9 rad a double's step is 1.2e-7 rad,
    // still below any error worth measuring; far beyond, the truth is lost in the rounding.
    static constexpr double kMaxRemovableRad = 1e9;
    static constexpr int kMaxHarmonic = 64;
    static constexpr int kAngleBins = 1024;  // distinct-angle coverage, for the harmonic order
    explicit Scorer(double settle_s);
    explicit Scorer(ScoringOptions o);
    // omega_true / omega_hat may be null; non-finite omega_true entries mean "rate unknown".
    void add(std::size_t n, const double* t_s, const double* theta_true, const double* omega_true,
             const double* theta_hat, const double* omega_hat, const std::uint8_t* valid);
    ErrorMetrics finish();

    // Scored errors (rad, the 2*pi multiple removed) are also handed to this sink in order,
    // with a flag that is 0 where the sample was not scored after the settle time (a gap).
    using Sink = std::function<void(std::size_t n, const double* e_rad, const std::uint8_t* scored)>;
    void set_sink(Sink s) { sink_ = std::move(s); }

private:
    // Samples after the settle time in order: e_raw = theta_hat - theta_true, ok = valid.
    void process(std::size_t n, const double* e_raw, const double* th, const std::uint8_t* ok);
    void decide();
    void harmonic_sums();
    ScoringOptions o_;
    bool decided_ = false;
    double offset_rad_ = 0;
    std::vector<double> pending_e_, pending_th_;
    std::vector<std::uint8_t> pending_ok_;
    std::size_t pending_good_ = 0;  // usable samples pending
    ErrorMetrics m_;
    double t0_ = 0;
    bool have_t0_ = false;
    double first_t_after_ = 0;
    bool locked_now_ = false;
    // Running moments (merged per block, Chan et al.)
    double mean_ = 0, m2_ = 0, min_e_ = 1e300, max_e_ = -1e300;
    double om_mean_ = 0, om_m2_ = 0;
    std::uint64_t om_n_ = 0;
    double sum_omega_true_ = 0, sum_abs_omega_true_ = 0;
    std::uint64_t n_omega_true_ = 0;
    // Batch means for the correlation time: level l holds batches of 64 * 2^l scored samples.
    struct BatchLevel { double partial = 0; int parts = 0; double s1 = 0, s2 = 0; std::uint64_t n = 0; };
    static constexpr int kBatchLevels = 11;  // 64 .. 65536
    static constexpr int kBatch0 = 64;
    BatchLevel batches_[kBatchLevels];
    double batch0_sum_ = 0;
    int batch0_n_ = 0;
    void batch_done(double sum);
    bool have_last_th_ = false;
    double last_th_ = 0;
    // Harmonic least squares on rows [1, cos k th, sin k th], k = 1..K: the normal equations
    // need only sums of cos(m th), sin(m th) for m = 0..2K and of e*cos(k th), e*sin(k th).
    std::vector<double> sum_cos_, sum_sin_, sum_ecos_, sum_esin_;
    double sum_e_ = 0, sum_e2_ = 0;
    // Fine angle bins over the electrical cycle: count and sums of u^p, e*u^p (p = 0..4) with u
    // the offset from the bin centre (rad); the harmonic sums and the angle coverage come from them.
    static constexpr int kFineBins = 8192;
    struct FineBin { double p[5] = {}, q[5] = {}; };
    std::vector<FineBin> fine_;
    // block scratch
    std::vector<double> blk_e_, sel_e_, sel_th_, sel_omt_, sel_omh_, rate_d_, es_, th_, e_;
    std::vector<std::uint8_t> blk_ok_, sel_ok_;
    std::vector<std::int32_t> fine_bin_;  // each scored sample's fine bin, and its offset from the centre
    std::vector<double> fine_u_;
    Sink sink_;
};

// Signs that an estimator's output does not follow fringe's conventions (theta unwrapped, in
// radians): jumps of 2*pi between consecutive samples while the truth moves smoothly (radians,
// wrapped), or a rate 180/pi times the truth's (degrees), with or without jumps of 360 (degrees
// wrapped to [0, 360) or (-180, 180]). Fed every sample with valid estimates and known truth.
// A finding is an evidence check of the run (docs/model.md "Output conventions"): a lane with
// one never PASSes.
class ConventionCheck {
public:
    void add(std::size_t n, const double* theta_true, const double* theta_hat, const std::uint8_t* valid);
    struct Finding { std::string code, message; };
    std::vector<Finding> findings() const;

private:
    bool have_ = false;
    double last_true_ = 0, last_hat_ = 0;
    std::uint64_t pairs_ = 0, wrap_jumps_ = 0;
    double sum_abs_dtrue_ = 0, sum_abs_dhat_ = 0;
    // Degrees: pairs whose output step is beyond 180 (no valid degree output moves half a turn
    // between two samples, since the truth moves less than pi rad) are wrap jumps of 360; the
    // rate ratio is measured over the other pairs.
    std::uint64_t deg_pairs_ = 0, deg_jumps_ = 0;
    double deg_sum_abs_dtrue_ = 0, deg_sum_abs_dhat_ = 0;
    double min_hat_ = 1e300, max_hat_ = -1e300;
};

// Angles in the report's three units (docs/schema.md): electrical rad, % of a signal period,
// mechanical arcsec.
nlohmann::json angle_units(double rad, int lines_per_rev);
nlohmann::json to_json(const ErrorMetrics& m, int lines_per_rev);
// 95 % intervals of the error figures from the number of independent samples they rest on
// (metrics "uncertainty"; docs/model.md#uncertainty).
nlohmann::json uncertainty_json(const ErrorMetrics& m);

}  // namespace fringe
