#include "server/engine/preflight.hpp"

#include "drivers/device.hpp"
#include "estimator/estimator.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/generator.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

namespace fringe {

namespace {

std::string fmt(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.3g", v);
    return b;
}

double peak_signal_v_of(const EncoderProfile& enc) {
    MotionProfile still;
    Generator g(enc, still, 1.0, 0);
    double peak = 0;
    for (int k = 0; k < 720; ++k) {
        double s, c;
        g.clean_channels(kTwoPi * k / 720.0, enc.kappa_nominal(), s, c);
        peak = std::max({peak, std::fabs(s), std::fabs(c)});
    }
    return peak;
}

}  // namespace

double peak_signal_v(const EncoderProfile& enc) { return peak_signal_v_of(enc); }

std::vector<Finding> amplitude_findings(const Scenario& sc, const nlohmann::json& signal) {
    std::vector<Finding> w;
    if (!signal.is_object() || signal.value("periods", 0) == 0) return w;
    const auto half_range = [&](const char* ch) {
        const nlohmann::json c = signal.value(ch, nlohmann::json());
        if (!c.is_object() || !c.value("max_v", nlohmann::json()).is_number() || !c.value("min_v", nlohmann::json()).is_number()) return 0.0;
        return 0.5 * (c["max_v"].get<double>() - c["min_v"].get<double>());
    };
    const double measured_v = std::max(half_range("a"), half_range("b"));
    if (!(measured_v > 0)) return w;
    for (std::size_t i = 0; i < sc.estimators.size(); ++i) {
        const auto& e = sc.estimators[i];
        if (!est::traits_of(e.name).told_amplitude) continue;
        const EncoderProfile& told = e.encoder ? *e.encoder : sc.encoder;
        const double told_v = peak_signal_v_of(told);
        if (!(told_v > 0) || (measured_v / told_v >= 0.8 && measured_v / told_v <= 1.25)) continue;
        w.push_back({false, "amplitude_mismatch", "estimators[" + std::to_string(i) + "]",
                     e.label + " is told a signal of " + fmt(told_v) + " V peak (its encoder profile" + (sc.encoder_known || e.encoder ? "" : ", none given: a default") +
                         ") but the signals measure " + fmt(measured_v) + " V peak: its model rejects or misreads them; tell it the signals' encoder "
                         "(vmax_v and the Lissajous gains) or use an estimator that learns the amplitude (ekf-selfcal, ekf-auto, atan2)"});
    }
    return w;
}

void to_json(nlohmann::json& j, const Finding& f) {
    j = {{"severity", f.error ? "error" : "warning"}, {"code", f.code}, {"field", f.field}, {"message", f.message}};
}

double min_samples_per_cycle(const Scenario& sc) {
    // The largest electrical phase step between two consecutive samples, from (a) the peak
    // rate over a dense grid of the run and (b) exact phase differences in windows spread over
    // the run (motions with jumps: steps, tables).
    const std::uint64_t total = sc.samples();
    const double T = 1.0 / sc.sample_rate_hz;
    const double lines = static_cast<double>(sc.encoder.lines_per_rev);
    double max_step_rad = 0;
    const std::size_t grid = static_cast<std::size_t>(std::min<std::uint64_t>(total, 200000));
    // The grid a chunk at a time: the whole 6.4 MB (about 1 600 pages
    // faulted in) took 20 ms of every run's start.
    constexpr std::size_t kChunk = 4096;
    std::vector<double> t(kChunk), phi(kChunk), om(kChunk), al(kChunk);
    for (std::size_t c0 = 0; c0 < grid; c0 += kChunk) {
        const std::size_t m = std::min(kChunk, grid - c0);
        for (std::size_t i = 0; i < m; ++i)
            t[i] = sc.t0_s + (grid > 1 ? sc.duration_s * static_cast<double>(c0 + i) / static_cast<double>(grid - 1) : 0.0);
        sc.motion.evaluate(t.data(), m, phi.data(), om.data(), al.data());
        for (std::size_t i = 0; i < m; ++i) max_step_rad = std::max(max_step_rad, std::fabs(om[i]) * lines * T);
    }
    const std::size_t windows = total <= 262144 ? 1 : 64;
    const std::size_t len = windows == 1 ? static_cast<std::size_t>(total) : 4096;
    t.resize(len); phi.resize(len); om.resize(len); al.resize(len);
    for (std::size_t w = 0; w < windows; ++w) {
        const std::uint64_t first = windows == 1 ? 0 : (total - len) * w / (windows - 1);
        for (std::size_t i = 0; i < len; ++i) t[i] = sc.t0_s + static_cast<double>(first + i) * T;
        sc.motion.evaluate(t.data(), len, phi.data(), om.data(), al.data());
        for (std::size_t i = 1; i < len; ++i) max_step_rad = std::max(max_step_rad, std::fabs(phi[i] - phi[i - 1]) * lines);
    }
    return max_step_rad > 0 ? kTwoPi / max_step_rad : kInf;
}

std::vector<Finding> preflight(const Scenario& sc, double spc, const dev::UriParts& input) {
    std::vector<Finding> w;
    if (sc.settle_s >= sc.duration_s) {
        // A capture holds what it holds: its run says that nothing was scored (the evidence
        // checks FAIL it) instead of refusing it.
        if (sc.instruments || sc.device.rfind("capture:", 0) != 0)
            throw ConfigError("settle_s", "the settle time (" + fmt(sc.settle_s) + " s) is not shorter than the run (duration_s " +
                                              fmt(sc.duration_s) + " s): nothing would be scored");
        w.push_back({false, "settle_covers_capture", "settle_s",
                     "the settle time (" + fmt(sc.settle_s) + " s) is not shorter than the capture (" + fmt(sc.duration_s) + " s): nothing will be scored"});
    }
    if (spc < 2.0) {
        // Enough digits that a rate just below the limit does not print as the limit itself.
        auto fine = [](double v) {
            char b[32];
            std::snprintf(b, sizeof b, "%.10g", v);
            return std::string(b);
        };
        // The peak speed in the units a person types: a speed in rpm typed as rad/s (x9.55) shows here.
        const double f_el_hz = sc.sample_rate_hz / spc, rev_s = f_el_hz / static_cast<double>(sc.encoder.lines_per_rev);
        auto plain = [](double v) {  // 5730 rpm, not 5.73e+03
            char b[32];
            std::snprintf(b, sizeof b, std::fabs(v) >= 100 && std::fabs(v) < 1e12 ? "%.0f" : "%.3g", v);
            return std::string(b);
        };
        throw ConfigError("sample_rate_hz", "undersampled: " + fine(spc) + " (< 2) samples per electrical cycle at the peak speed of " + plain(kTwoPi * rev_s) +
                                                " rad/s = " + plain(60.0 * rev_s) + " rpm (" + plain(f_el_hz) + " Hz electrical with " +
                                                std::to_string(sc.encoder.lines_per_rev) + " lines); at least 2 are needed, and 4 or more to track. "
                                                "Raise sample_rate_hz above " + fine(2 * sc.sample_rate_hz / spc) + " Hz or lower the speed "
                                                "(velocity_rad_s is in rad/s: 600 rpm is 62.8 rad/s)");
    }
    if (spc < 4.0)
        w.push_back({false, "few_samples_per_cycle", "sample_rate_hz",
                     fmt(spc) + " samples per electrical cycle at the peak speed: trackers lose lock and harmonics alias below about 4"});
    for (std::size_t i = 0; i < sc.estimators.size(); ++i) {
        const auto& e = sc.estimators[i];
        const std::string f = "estimators[" + std::to_string(i) + "]";
        if (e.params.is_object() && e.params.contains("natural_freq_hz") && e.params["natural_freq_hz"].is_number()) {
            const double fn = e.params["natural_freq_hz"].get<double>();
            if (fn > sc.sample_rate_hz / 20)
                w.push_back({false, "bandwidth_near_sample_rate", f + ".params.natural_freq_hz",
                             e.label + ": tracker natural frequency " + fmt(fn) + " Hz is within a factor 20 of the sample rate " +
                                 fmt(sc.sample_rate_hz) + " Hz: the loop is barely discrete-time stable and its bound assumptions fail"});
        }
        const est::EstimatorTraits traits = est::traits_of(e.name);
        if (traits.learns_over_cycles > 0) {
            // told nothing, it learns the shape from the motion (ekf-auto: ~50 electrical cycles, docs/estimators.md)
            const std::string& tp = traits.told_param;
            const bool told = !tp.empty() && e.params.is_object() && e.params.contains(tp) && e.params[tp].is_boolean() && e.params[tp].get<bool>();
            // the distance travelled, not the net one: a swinging motion learns on every swing
            constexpr std::size_t kN = 4001;
            std::vector<double> t(kN), ph(kN), om(kN), al(kN);
            const double span = std::min(sc.settle_s, sc.duration_s);
            for (std::size_t k = 0; k < kN; ++k) t[k] = sc.t0_s + span * static_cast<double>(k) / (kN - 1);
            sc.motion.evaluate(t.data(), kN, ph.data(), om.data(), al.data());
            double travelled_rad = 0;
            for (std::size_t k = 1; k < kN; ++k) travelled_rad += std::fabs(ph[k] - ph[k - 1]);
            const double cycles = travelled_rad * static_cast<double>(sc.encoder.lines_per_rev) / kTwoPi;
            if (!told && cycles < traits.learns_over_cycles)
                w.push_back({false, "scores_learning", "settle_s",
                             e.label + (e.label == e.name ? "" : " (" + e.name + ")") + " learns the waveform shape over about " +
                                 fmt(traits.learns_over_cycles) + " electrical cycles of motion; the settle time of " +
                                 fmt(sc.settle_s) + " s covers " + fmt(cycles) +
                                 " electrical cycles of travel, so its score includes its learning (raise settle_s)"});
        }
        if (traits.assumes_ideal_sinusoids && sc.encoder.model == ModelKind::Diffraction) {
            bool limited = false;
            for (const auto& l : sc.limits) limited |= (l.estimator == "*" || l.estimator == e.label) && l.max;
            if (limited)
                w.push_back({false, "model_mismatch", f + ".name",
                             e.label + " (" + e.name + ") assumes ideal sinusoids but the encoder is a diffraction model: its error is "
                                       "dominated by the waveform's harmonics (about 1.6e-2 rad on the paper's signal), not by noise"});
        }
    }
    // The device's converter, as far as the URI says (loopback).
    if (input.scheme == "loopback") {
        const int adc_bits = input.settings.value("adc_bits", 16);
        const double range_v = input.settings.value("range_v", 1.25);
        if (adc_bits > 0 && !sc.encoder.adc.ideal())
            w.push_back({false, "double_quantisation", "encoder.adc.bits",
                         "the encoder profile has its own " + std::to_string(sc.encoder.adc.bits) + "-bit ADC and the device digitises again at " +
                             std::to_string(adc_bits) + " bits: the signal is quantised twice (use a profile with adc.bits = 0 for runs)"});
        const double peak = peak_signal_v_of(sc.encoder) + 4 * sc.encoder.noise.sigma_add_v;
        if (peak >= range_v)
            w.push_back({false, "clipping", "device",
                         "the signal reaches " + fmt(peak) + " V (peak plus 4 sigma of noise) but the converters span +-" + fmt(range_v) +
                             " V: it clips"});
    }
    if (!sc.encoder.adc.ideal()) {
        const double peak = peak_signal_v_of(sc.encoder);
        if (peak >= sc.encoder.adc.max_v || -peak < sc.encoder.adc.min_v)
            w.push_back({false, "clipping", "encoder.adc", "the encoder's own ADC spans " + fmt(sc.encoder.adc.min_v) + ".." +
                                                              fmt(sc.encoder.adc.max_v) + " V but the signal reaches +-" + fmt(peak) + " V: it clips"});
    }
    return w;
}

std::vector<Finding> preflight_device(const Scenario& sc, const dev::DeviceInfo& d) {
    std::vector<Finding> w;
    if (d.driver == "loopback") return w;  // checked from the URI already
    const auto& c = d.converter;
    if (c.known && c.adc_q_v() > 0 && !sc.encoder.adc.ideal() && d.driver != "capture")
        w.push_back({false, "double_quantisation", "encoder.adc.bits",
                     "the encoder profile has its own ADC and " + d.driver + " digitises again: the signal is quantised twice"});
    if (c.known && c.adc_range_v > 0) {
        const double peak = peak_signal_v_of(sc.encoder);
        if (peak >= c.adc_range_v)
            w.push_back({false, "clipping", "device", "the signal reaches " + fmt(peak) + " V but the device's ADC spans +-" + fmt(c.adc_range_v) + " V"});
    }
    // A unipolar DAC (a LabJack's 0..5 V) with the signal at mid-scale has less room than its ADC.
    if (c.known && c.dac_range_v > 0 && c.dac_range_v != c.adc_range_v) {
        const double peak = peak_signal_v_of(sc.encoder);
        if (peak >= c.dac_range_v)
            w.push_back({false, "clipping", "device", "the signal reaches " + fmt(peak) + " V but the device's DAC spans +-" + fmt(c.dac_range_v) +
                                                          " V around the signal's zero"});
    }
    return w;
}

}  // namespace fringe
