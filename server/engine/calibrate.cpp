#include "calibrate.hpp"

#include "drivers/capture_file.hpp"
#include "server/analysis/calibration.hpp"
#include "server/engine/capture_run.hpp"
#include "signal_gen/fastmath.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <vector>

namespace fringe {

using nlohmann::json;

namespace {

// Each sample of the capture as atan2 reads it with the correction's Lissajous stage (phi_rad; the
// calibration it is told where the correction has none) and with the calibration it is told
// (phi_told_rad), with its time from the first sample. Samples that are not finite are skipped.
template <class F>
void for_each_reading(const CalibrateOptions& o, const est::Correction& c, F&& f) {
    CaptureReader reader(o.capture_path, o.capture);
    std::optional<EncoderProfile> told = o.encoder;
    if (!told && reader.meta().is_object() && reader.meta().contains("encoder"))
        told = encoder_from_json(reader.meta()["encoder"], "capture.encoder");
    const est::Calibration nominal = est::nominal_calibration(told, resolve_params(est::calibration_params(), json::object()));
    est::Calibration lis = nominal;
    if (c.has_lissajous) c.lissajous_into(lis);
    CaptureData d;
    bool first = true;
    double t0_s = 0;
    while (reader.read(65536, d))
        for (std::size_t i = 0; i < d.size(); ++i) {
            if (first) { t0_s = d.t_s[i]; first = false; }
            double sn, cn, sn0, cn0;
            lis.normalise(d.sin_v[i], d.cos_v[i], sn, cn);
            nominal.normalise(d.sin_v[i], d.cos_v[i], sn0, cn0);
            const double phi_rad = std::atan2(sn, cn), phi_told_rad = std::atan2(sn0, cn0);
            if (std::isfinite(phi_rad) && std::isfinite(phi_told_rad)) f(d.t_s[i] - t0_s, phi_rad, phi_told_rad);
        }
}

// Without truth the zero of the angle is not observable, but the Lissajous stage moves it (the
// ellipse fit of a distorted signal is biased): the offset that keeps the corrected angle's mean
// where the estimator's, with the calibration it is told, had it over the capture.
double kept_zero(const CalibrateOptions& o, const est::Correction& c) {
    double sum = 0;
    std::uint64_t n = 0;
    for_each_reading(o, c, [&](double, double phi_rad, double phi_told_rad) {
        sum += wrap_pi(phi_rad - c.table_value(phi_rad) - phi_told_rad);
        ++n;
    });
    return n ? sum / static_cast<double>(n) : 0.0;
}

// A sparse record (a 128-step sweep) may miss an arc here and there: what is refused is a gap
// of more than kMaxGapBins arcs in a row (22.5 degrees), where the table would be extrapolated.
constexpr int kCoverageBins = 64, kMaxGapBins = 4;
struct Coverage {
    int visited = 0, largest_gap = 0;  // arcs seen; the longest run of arcs not seen (around the circle)
};

// The scored samples' angles as atan2 reads them (those after the settle time), read from the
// capture once: per fine bin of the period, the count and the sum of the angle. Coverage and the
// table's mean over the record (in each pass of the constant's fixed point) come from it. The
// table is linear within a fine bin (2^16 of them) but for the bins that hold one of its nodes,
// so its mean over a bin's samples is its value at their mean angle.
class AngleRecord {
public:
    AngleRecord(const CalibrateOptions& o, double settle_s, const est::Correction& c) : count_(kFine, 0), sum_rad_(kFine, 0.0) {
        for_each_reading(o, c, [&](double t_s, double phi_rad, double) {
            if (t_s < settle_s) return;
            double u = phi_rad / kTwoPi;
            u -= std::floor(u);
            const std::size_t b = std::min(kFine - 1, static_cast<std::size_t>(u * static_cast<double>(kFine)));
            ++count_[b];
            sum_rad_[b] += u * kTwoPi;
            ++n_;
        });
    }

    // The table's mean over the record. Against truth the offset is the error's mean less this:
    // the corrected record's mean is then zero. Over whole periods sampled evenly it is zero, but
    // a record that is not (a step sweep that skips or repeats a step, a motion that speeds up)
    // weights the angles unevenly: with the paper's 4e-2 rad 1x error one step in 128 moved the
    // mean by 5.6e-4 rad.
    double table_mean_rad(const est::Correction& c) const {
        double sum = 0;
        for (std::size_t b = 0; b < kFine; ++b)
            if (count_[b]) sum += static_cast<double>(count_[b]) * c.table_value(sum_rad_[b] / static_cast<double>(count_[b]));
        return n_ ? sum / static_cast<double>(n_) : 0.0;
    }

    // Of kCoverageBins equal arcs of the period, how many the record visits, and the longest run
    // it never does. Travel is not coverage: +-1 rad back and forth for 11 "cycles" fitted
    // harmonics to a third of the circle, and the table was garbage elsewhere (2.4e-2 rad measured
    // on another capture, worse than no correction, where 2.7e-4 was predicted).
    Coverage coverage() const {
        std::vector<char> seen(kCoverageBins, 0);
        for (std::size_t b = 0; b < kFine; ++b)
            if (count_[b]) seen[b / (kFine / kCoverageBins)] = 1;
        Coverage cov;
        cov.visited = static_cast<int>(std::count(seen.begin(), seen.end(), 1));
        if (cov.visited == 0) return {0, kCoverageBins};
        int run = 0;
        for (int i = 0; i < 2 * kCoverageBins; ++i) {  // twice around: a gap across angle 0
            run = seen[static_cast<std::size_t>(i % kCoverageBins)] ? 0 : run + 1;
            cov.largest_gap = std::max(cov.largest_gap, std::min(run, kCoverageBins));
        }
        return cov;
    }

private:
    static constexpr std::size_t kFine = std::size_t{1} << 16;
    std::vector<std::uint64_t> count_;
    std::vector<double> sum_rad_;  // the angles wrapped to [0, 2 pi)
    std::uint64_t n_ = 0;
};

}  // namespace

CalibrateResult calibrate_capture(const CalibrateOptions& o) {
    if (o.estimator != "atan2") throw ConfigError("estimator", "only atan2 can be calibrated so far");
    CalibrateResult res;
    bool has_truth = false;
    {
        // The settle time: the one given, else the one the capture was recorded with (a Modbus
        // sweep of 0.128 s recorded with settle_s 0 has nothing after a default 0.1 s), else 0.1 s.
        CaptureReader reader(o.capture_path, o.capture);
        has_truth = reader.columns().theta_true;
        const json& meta = reader.meta();
        res.settle_s = 0.1;
        res.settle_from = "default";
        if (o.settle_s) {
            res.settle_s = *o.settle_s;
            res.settle_from = "given";
        } else if (const auto recorded = recorded_settle_s(meta)) {
            res.settle_s = *recorded;
            res.settle_from = "capture";
        }
    }
    json params = json::object();
    json lis;
    if (o.lissajous) {
        LissajousIdentifier id;
        CaptureReader reader(o.capture_path, o.capture);
        CaptureData d;
        while (reader.read(65536, d)) id.add(d.size(), d.sin_v.data(), d.cos_v.data());
        est::Calibration cal;
        const std::string why = id.finish(cal);
        if (!why.empty()) throw std::runtime_error("ellipse fit of the signals rejected: " + why);
        res.correction.lissajous_from(cal);
        params = cal.to_json();
        lis = {{"method", "Heydemann ellipse fit"}, {"points", id.points()}};
    }
    CaptureRunOptions ro;
    ro.capture_path = o.capture_path;
    ro.estimator = o.estimator;
    ro.params = params;
    ro.encoder = o.encoder;
    ro.settle_s = res.settle_s;
    ro.capture = o.capture;
    if (o.error_source != "auto" && o.error_source != "truth" && o.error_source != "self_reference")
        throw ConfigError("error_source", "'" + o.error_source + "': auto, truth or self_reference");
    if (o.error_source == "truth" && !has_truth)
        throw ConfigError("error_source", "truth, but the capture has no theta_true column: calibrate from the self-referenced error (auto or self_reference)");
    const bool use_truth = has_truth && o.error_source != "self_reference";
    ro.self_reference = !use_truth;
    const RunReport rep = run_capture(ro);
    if (rep.status != RunStatus::Done || rep.estimators.empty())
        throw std::runtime_error("the run of " + o.estimator + " on the capture failed: " + rep.error);
    const json lane = rep.estimators.front();
    const json& m = lane.at("metrics");
    std::vector<ErrorHarmonic> h;
    double mean = 0;
    json rests;
    // Too short a record fits its noise: a correction needs min_cycles electrical cycles under it.
    auto enough = [&](double cycles, const char* what) {
        if (!(cycles >= o.min_cycles)) {
            char msg[256];
            std::snprintf(msg, sizeof msg, "too few electrical cycles for a correction: %.3g %s after the settle time (at least %g)", cycles, what, o.min_cycles);
            throw std::runtime_error(msg);
        }
    };
    if (use_truth && m.value("scored", std::uint64_t{0}) > 0) {  // the capture has truth
        enough(m.at("evidence").value("scored_cycles", 0.0), "scored");
        if (!m.contains("harmonics") || !m.at("harmonics").is_array() || m.at("harmonics").empty())
            throw std::runtime_error("the error's harmonics were not fitted: " + m.at("harmonic_analysis").value("note", std::string("no reason given")));
        res.source = "truth";
        for (const auto& x : m.at("harmonics"))
            h.push_back({x.at("order").get<int>(), x.at("amplitude").at("rad").get<double>(), x.at("phase_rad").get<double>()});
        mean = m.at("mean").at("rad").get<double>();
        res.before_rms_rad = m.at("rms").at("rad").get<double>();
        res.noise_rms_rad = m.at("harmonic_analysis").at("broadband_rms_rad").get<double>();
        rests = {{"scored_samples", m.at("evidence").at("scored_samples")}, {"scored_cycles", m.at("evidence").at("scored_cycles")},
                 {"orders_fitted", m.at("harmonic_analysis").at("orders_fitted")}};
    } else if (use_truth) {
        // Truth, but nothing scored: say why, not that the truth is missing.
        const json ev = m.value("evidence", json::object());
        char msg[320];
        std::snprintf(msg, sizeof msg,
                      "nothing scored against the capture's truth: %llu samples after the %.6g s settle time (%s), %llu of them valid "
                      "(give a shorter --settle-s, or a longer capture)",
                      static_cast<unsigned long long>(ev.value("samples_after_settle", std::uint64_t{0})), res.settle_s,
                      res.settle_from == "given" ? "given" : res.settle_from == "capture" ? "the capture's own" : "the default",
                      static_cast<unsigned long long>(ev.value("samples_after_settle", std::uint64_t{0}) - std::min(ev.value("samples_after_settle", std::uint64_t{0}), m.value("invalid_after_settle", std::uint64_t{0}))));
        throw std::runtime_error(msg);
    } else {
        const json sr = lane.value("analysers", json::object()).value("self_reference", json());
        if (!sr.is_object() || !sr.value("measured", false))
            throw std::runtime_error(std::string(has_truth ? "no self-referenced error (chosen over the capture's truth): "
                                                           : "the capture has no truth and no self-referenced error: ") +
                                     (sr.is_object() ? sr.value("why_not", std::string("not measured")) : std::string("not measured")));
        enough(sr.value("cycles", 0.0), "in the self-referenced windows");
        res.source = "self_reference";
        for (const auto& x : sr.at("harmonics"))
            h.push_back({x.at("order").get<int>(), x.at("amplitude_rad").get<double>(), x.at("phase_rad").get<double>()});
        mean = sr.at("mean_vs_reference_rad").get<double>();
        res.before_rms_rad = sr.at("rms_rad").get<double>();
        res.noise_rms_rad = sr.at("residual_rms_rad").get<double>();
        rests = {{"windows", sr.at("windows")}, {"cycles", sr.at("cycles")}, {"samples", sr.at("samples")},
                 {"orders_fitted", h.size()}};
    }
    const AngleRecord record(o, res.settle_s, res.correction);  // the Lissajous stage is final: atan2's angles are too
    if (const Coverage cov = record.coverage(); cov.largest_gap > kMaxGapBins) {
        char msg[400];
        std::snprintf(msg, sizeof msg,
                      "the record does not cover the electrical period: %d of %d arcs visited after the settle time, %d in a row never seen "
                      "(%.0f degrees; at most %d allowed). A correction needs the whole circle: a motion that swings back and forth over part "
                      "of a period travels cycles without seeing the rest",
                      cov.visited, kCoverageBins, cov.largest_gap, 360.0 * cov.largest_gap / kCoverageBins, kMaxGapBins);
        throw std::runtime_error(msg);
    }
    PeriodicOptions po;
    po.table_size = o.table_size;
    po.harmonics = o.harmonics;
    // The record's mean m is the error's constant C plus the mean of its harmonics over the
    // angles the record visited: over whole cycles sampled evenly that is C, but over 1.3 cycles
    // of the paper's signal m was C + 6.5e-3 rad, and inverting e(s) = m + harmonics put the
    // table at angles 6.5e-3 rad off (3.8e-4 rad measured on another capture against 2.3e-4 with
    // C). C is the fixed point C = m - (the table's mean over the record), a few passes over the record.
    PeriodicFit f;
    double constant_rad = mean;
    try {
        for (int pass = 0; pass < 6; ++pass) {
            f = periodic_correction(h, constant_rad, po);
            const double next_rad = mean - record.table_mean_rad(f.correction);
            const bool settled = std::fabs(next_rad - constant_rad) < 1e-9;
            constant_rad = next_rad;
            if (settled) break;
        }
        f = periodic_correction(h, constant_rad, po);
    } catch (const std::invalid_argument& e) {
        throw std::runtime_error(e.what());
    }
    res.correction.cos_k = f.correction.cos_k;
    res.correction.sin_k = f.correction.sin_k;
    res.correction.table = f.correction.table;
    // Against a truth the error's mean is an error too (the ellipse fit of a distorted signal
    // shifts it); against the self-referenced reference it is the signals' phase convention.
    if (res.source == "truth") res.correction.offset_rad = mean - record.table_mean_rad(res.correction);
    else if (res.correction.has_lissajous) res.correction.offset_rad = kept_zero(o, res.correction);
    res.periodic_rms_rad = f.error_rms_rad;
    res.table_residual_rms_rad = f.table_residual_rms_rad;
    res.predicted_rms_rad = res.source == "truth"
                                ? predicted_residual_rad(f.table_residual_rms_rad, res.noise_rms_rad, rests["scored_samples"].get<double>(),
                                                         rests["orders_fitted"].get<int>())
                                : predicted_residual_rad(f.table_residual_rms_rad, res.noise_rms_rad);
    if (lane.contains("bounds") && lane.at("bounds").contains("per_sample_crb_rad") && lane.at("bounds").at("per_sample_crb_rad").is_number())
        res.per_sample_crb_rad = lane.at("bounds").at("per_sample_crb_rad").get<double>();
    res.facts = {{"capture", o.capture_path},
                 {"estimator", o.estimator},
                 {"error_source", res.source},
                 {"lissajous", lis},
                 {"record", rests},
                 {"settle_s", res.settle_s},
                 {"settle_from", res.settle_from},
                 {"before_rms_rad", res.before_rms_rad},
                 {"periodic_rms_rad", res.periodic_rms_rad},
                 {"max_error_slope", f.max_slope},
                 {"table_residual_rms_rad", res.table_residual_rms_rad},
                 {"noise_rms_rad", res.noise_rms_rad},
                 {"predicted_rms_rad", res.predicted_rms_rad},
                 {"per_sample_crb_rad", res.per_sample_crb_rad > 0 ? json(res.per_sample_crb_rad) : json()}};
    return res;
}

}  // namespace fringe
