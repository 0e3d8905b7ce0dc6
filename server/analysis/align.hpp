// Truth alignment across clocks (issue 14, docs/alignment.md): a waveform generator plays what
// fringe synthesised, a digitizer on its own clock records it. From the two signals alone this
// estimates where each recorded sample lies on the generator's time axis:
//     tau(m) = tau0_s + m * (1 + clock_offset_ppm * 1e-6) / record_rate_hz
// and each channel's gain and offset (recorded = gain * played(tau) + offset). A pure function
// of the samples: unit-tested without devices. An alignment that is not confident comes back
// with ok = false and the reason, never as a guess.
#pragma once

#include <nlohmann/json.hpp>

#include <cstddef>
#include <span>
#include <string>

namespace fringe {

struct AlignInput {
    // What the generator played (V), at play_rate_hz on its own clock; cyclic: the block repeats
    // until the output stops. Before its first sample (and after its last when not cyclic) the
    // output is taken as idle (0 V).
    std::span<const double> played_sin_v, played_cos_v;
    double play_rate_hz = 0;
    bool cyclic = false;
    // What the digitizer recorded (V), at its nominal rate on its own clock. The record must
    // start no later than the output (the Device contract): the onset resolves whole periods.
    std::span<const double> recorded_sin_v, recorded_cos_v;
    double record_rate_hz = 0;
};

struct AlignOptions {
    double max_clock_offset_ppm = 1000;     // supported clock offsets; larger estimates are refused, named as such
    double search_clock_offset_ppm = 2000;  // the coarse search's range (beyond the supported one, so an offset just outside is named)
    double min_correlation = 0.5;           // normalised cross-correlation at the coarse peak
    double max_residual_relative = 0.2;     // fit residual rms / recorded signal rms
    double min_ambiguity_z = 10;            // significance by which the best alignment must beat the next
    double max_delay_std_samples = 0.05;    // standard error of the delay, record samples
    std::size_t max_fit_samples = 1u << 19; // the fit uses every k-th sample beyond this
    // A channel whose recorded amplitude (peak, V) is below the larger of these is flat
    // (disconnected, shorted): min_amplitude_v, or min_amplitude_ratio of the other channel's.
    double min_amplitude_v = 1e-3;
    double min_amplitude_ratio = 0.1;
    // The whole record (idle output before and after included) must fit within this factor of
    // the residual inside the played span, plus record_residual_allowance of the signal rms.
    double max_record_residual_factor = 2.0;
    double record_residual_allowance = 0.01;
    // Samples that are not finite, or lie beyond outlier_factor times the record's 90th
    // percentile deviation from its median (or 1e6 V) are left out; more than this share is refused.
    double outlier_factor = 20;
    double max_outlier_fraction = 0.01;
};

struct AlignChannel {
    double gain = 0, offset_v = 0;
    double amplitude_v = 0;  // |gain| x the played channel's peak amplitude: what the input saw (V)
};

struct AlignResult {
    bool ok = false;
    std::string error;  // when !ok: why the alignment is not confident
    // tau(m) = tau0_s + m * (1 + clock_offset_ppm * 1e-6) / record_rate_hz (generator seconds).
    double tau0_s = 0, clock_offset_ppm = 0, record_rate_hz = 0;
    // Time from the record's first sample until the generator's first sample appears at the
    // input, in the digitizer's seconds (-tau0 / (1 + ppm * 1e-6)); negative: the record
    // started after the output.
    double delay_s = 0;
    AlignChannel sin, cos;
    // Wiring the best fit found: the input's sin records the generator's cos (and vice versa);
    // an inverted channel is a negative gain. Either one makes the alignment refused.
    bool swapped = false;
    double residual_rms_v = 0;       // rms of recorded - model over the fitted samples, both channels
    double signal_rms_v = 0;         // rms of the recorded signal about its offsets, same samples
    double residual_relative = 0;    // residual_rms_v / signal_rms_v
    double record_residual_rms_v = 0;  // rms of recorded - model over the whole record (idle output included)
    std::size_t outlier_samples = 0;   // recorded samples left out (not finite, or absurdly far out)
    double coarse_clock_offset_ppm = 0;  // the coarse grid point the best candidate came from
    double search_clock_offset_ppm = 0, search_step_ppm = 0;  // the coarse search's range and grid step
    double correlation = 0;          // normalised cross-correlation at the coarse peak (-1..1)
    double correlation_sin = 0, correlation_cos = 0;  // per channel at that lag (diagnosis)
    double delay_std_s = 0, clock_offset_std_ppm = 0; // standard errors from the fit
    // How much worse (in standard deviations of the statistic) the next-best distinct
    // alignment fits the whole record; infinity when the coarse search found none.
    double ambiguity_z = 0;
    double alternative_shift_s = 0;  // the next-best alignment's tau0 minus the chosen one
    std::size_t fitted_samples = 0, candidates = 0;
    std::string method;

    double output_time_s(double m) const { return tau0_s + m * (1 + clock_offset_ppm * 1e-6) / record_rate_hz; }
};

AlignResult align(const AlignInput& in, const AlignOptions& o = {});

// Band-limited value of a played channel at generator time t_s (the interpolator the fit uses:
// Kaiser-windowed sinc, 24 taps each side). Exposed for tests.
double played_value(std::span<const double> played_v, double rate_hz, bool cyclic, double t_s);

void to_json(nlohmann::json& j, const AlignResult& r);

}  // namespace fringe
