#include "server/engine/capture_run.hpp"

#include "server/engine/evaluate.hpp"
#include "server/engine/run.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/fastmath.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <stdexcept>

namespace fringe {

using nlohmann::json;

namespace {

std::string number_text(double x) {
    char b[32];
    return std::string(b, std::to_chars(b, b + sizeof b, x).ptr);
}

// A value that goes into the device URI's query: nothing that would end it or start another key.
void check_uri_text(const std::string& s, const std::string& field, const std::string& what) {
    if (s.find_first_of("?&=#") != std::string::npos)
        throw ConfigError(field, what + " '" + s + "' contains one of ? & = #, which a capture: device URI cannot carry; rename it");
}

}  // namespace

std::optional<double> recorded_settle_s(const nlohmann::json& meta) {
    if (!meta.is_object() || !meta.contains("scenario") || !meta["scenario"].is_object()) return std::nullopt;
    const nlohmann::json& s = meta["scenario"];
    if (!s.contains("settle_s") || !s["settle_s"].is_number()) return std::nullopt;
    const double v = s["settle_s"].get<double>();
    if (!std::isfinite(v) || v < 0) return std::nullopt;
    return v;
}

CaptureScan scan_capture(const std::string& path, const CaptureOptions& options, double settle_s, std::size_t block) {
    CaptureReader reader(path, options);
    CaptureData d;
    CaptureScan sc;
    sc.has_truth = reader.columns().theta_true;
    sc.has_abz = reader.columns().abz();
    // A swing teaches ekf-auto on every pass: the distance, not the net travel; but the noise's
    // jitter of a standing encoder's phase is no travel. The phase (unwrapped), averaged over
    // groups of kGroup samples, is counted when it has moved kDeadbandRad from where it was last
    // counted, by the whole way it moved (a turn loses at most the deadband).
    constexpr double kDeadbandRad = 0.5;
    constexpr int kGroup = 16;
    double w_prev = 0, phase = 0, anchor = 0, group_sum = 0;
    int group_n = 0;
    bool have_prev = false, have_anchor = false, settle_closed = false;
    while (reader.read(block, d)) {
        const std::size_t m = d.size();
        if (m == 0) continue;
        if (sc.samples == 0) sc.t_first_s = d.t_s[0];
        for (std::size_t i = 0; i < m; ++i) {
            if (sc.has_truth) {
                if (!std::isfinite(d.theta_true_rad[i])) continue;
                phase = d.theta_true_rad[i];
                have_prev = true;
            } else if (std::isfinite(d.sin_v[i]) && std::isfinite(d.cos_v[i]) && (d.sin_v[i] != 0 || d.cos_v[i] != 0)) {
                const double w = std::atan2(d.sin_v[i], d.cos_v[i]);
                if (have_prev) {
                    double dw = w - w_prev;
                    dw -= kTwoPi * std::round(dw / kTwoPi);  // a step below pi a sample
                    phase += dw;
                }
                w_prev = w;
                have_prev = true;
            } else {
                continue;
            }
            group_sum += phase;
            if (++group_n < kGroup) continue;
            const double mean = group_sum / kGroup;
            group_sum = 0;
            group_n = 0;
            if (!have_anchor) {
                anchor = mean;
                have_anchor = true;
            }
            const double moved = std::fabs(mean - anchor);
            if (!std::isfinite(moved)) continue;
            const bool in_settle = d.t_s[i] - sc.t_first_s < settle_s;
            // Leaving the settle time: its travel takes what moved since the last count too.
            if (!in_settle && !settle_closed) {
                sc.settle_travel_rad = sc.travel_rad + moved;
                settle_closed = true;
            }
            if (moved < kDeadbandRad) continue;
            anchor = mean;
            sc.travel_rad += moved;
            if (in_settle) sc.settle_travel_rad += moved;
        }
        sc.samples += m;
    }
    if (!settle_closed) sc.settle_travel_rad = sc.travel_rad;
    sc.sample_rate_hz = reader.sample_rate_hz();
    if (!(sc.sample_rate_hz > 0)) throw CaptureError(path + ": sample rate unknown (no sidecar and fewer than two time stamps)");
    sc.meta = reader.meta();
    return sc;
}

MotionProfile capture_motion(const CaptureScan& scan, double settle_s, int lines_per_rev) {
    const double duration_s = static_cast<double>(scan.samples) / scan.sample_rate_hz;
    const double window = std::min(settle_s, duration_s);
    const double electrical_rad_s = window > 0 ? scan.settle_travel_rad / window : duration_s > 0 ? scan.travel_rad / duration_s : 0.0;
    MotionProfile m;
    m.kind = MotionKind::Constant;
    m.velocity_rad_s = electrical_rad_s / lines_per_rev;
    return m;
}

std::optional<Finding> self_reference_motion_check(const CaptureScan& scan, double settle_s) {
    const SelfReferenceOptions so;
    const double cycles = std::max(0.0, scan.travel_rad - scan.settle_travel_rad) / kTwoPi;
    const double duration_s = scan.sample_rate_hz > 0 ? static_cast<double>(scan.samples) / scan.sample_rate_hz : 0.0;
    const double scored_s = std::max(0.0, duration_s - settle_s);
    char b[400];
    if (cycles < 2 * so.window_cycles) {
        std::snprintf(b, sizeof b,
                      "the self-referenced error needs the motion to sweep the electrical angle: the capture travels %.3g electrical cycles after "
                      "the settle time, and a window spans %.0f (one of fewer than %.0f is skipped): expect few or no windows, or nothing measured",
                      cycles, so.window_cycles, so.min_window_cycles);
        return Finding{false, "self_reference_motion", "settle_s", b};
    }
    const double spc = scored_s > 0 ? scan.sample_rate_hz * scored_s / cycles : 0.0;  // mean samples per electrical cycle
    if (spc * so.min_window_cycles > static_cast<double>(so.max_window_samples)) {
        std::snprintf(b, sizeof b,
                      "the capture moves at %.3g samples per electrical cycle on average: a self-referenced window holds at most %zu samples, "
                      "fewer than the %.0f cycles it is measured on; most windows will be skipped (decimate the capture or capture faster motion)",
                      spc, so.max_window_samples, so.min_window_cycles);
        return Finding{false, "self_reference_motion", "sample_rate_hz", b};
    }
    return std::nullopt;
}

CapturePlan plan_capture_run(const CaptureRunOptions& o) {
    if (o.capture_path.find('?') != std::string::npos)
        throw ConfigError("capture", "the path '" + o.capture_path + "' contains '?', which a capture: device URI cannot carry; rename the file");
    // Read the capture once: its length (the run's planned samples), the first time stamp and
    // the travel. Every fault of the file is found here, before anything is written.
    const CaptureScan scan = scan_capture(o.capture_path, o.capture, o.settle_s, o.block);
    const bool truth = scan.has_truth;
    const std::uint64_t n = scan.samples;
    const double fs = scan.sample_rate_hz, t_first = scan.t_first_s;
    std::optional<EncoderProfile> from_capture;
    if (scan.meta.is_object() && scan.meta.contains("encoder"))
        from_capture = encoder_from_json(scan.meta["encoder"], "capture.encoder");
    if (o.abz) {
        if (!scan.has_abz)
            throw ConfigError("dut_interpolation", "the capture has no a/b lines to read a DUT's position from (docs/abz.md)");
        try {
            AbzDecoder check(*o.abz);
        } catch (const std::invalid_argument& e) {
            throw ConfigError("dut_interpolation", e.what());
        }
    }

    CapturePlan p;
    p.has_truth = truth;
    Scenario sc;
    sc.name = "estimate " + std::filesystem::path(o.capture_path).filename().string();
    sc.description = o.estimator + " on the capture " + o.capture_path;
    // The truth's units and bounds: the capture's own encoder, else the profile given; the
    // estimator is told the profile given, else the capture's.
    const std::optional<EncoderProfile>& truth_enc = from_capture ? from_capture : o.encoder;
    sc.encoder_known = truth_enc.has_value();
    if (truth_enc) sc.encoder = *truth_enc;
    sc.sample_rate_hz = fs;
    sc.duration_s = static_cast<double>(n) / fs;
    sc.t0_s = t_first;
    // The capture's own motion for the preflight (so the travel it finds over the settle time,
    // ekf-auto's learning rule, is the capture's) and the spectrum's segment length.
    sc.motion = capture_motion(scan, o.settle_s, sc.encoder.lines_per_rev);
    sc.motion_from_capture = true;
    sc.settle_s = o.settle_s;
    EstimatorSpec spec{o.estimator, o.estimator, o.params.is_null() ? json::object() : o.params, std::nullopt};
    if (o.encoder && from_capture) spec.encoder = o.encoder;  // told another profile than the truth's
    sc.estimators = {spec};
    // The device: the capture driver, with the channel map, the expanded-size cap and the DUT's readout.
    std::string uri = "capture:" + o.capture_path;
    std::vector<std::string> q;
    // The reader above held the file to the exact cap; the driver takes whole MiB from 1.
    const double mb = std::clamp(static_cast<double>(o.capture.max_expanded_bytes) / 1048576.0, 1.0, 1.6e7);
    q.push_back("max_expanded_mb=" + number_text(std::ceil(mb)));
    for (const auto& [col, ch] : o.capture.channels) {
        check_uri_text(ch, "channels", "the channel name");
        q.push_back(col + "=" + ch);
    }
    if (scan.has_abz) {
        if (o.abz) {
            q.push_back("interpolation=" + std::to_string(o.abz->interpolation));
            q.push_back("index_count=" + std::to_string(o.abz->index_count));
            q.push_back("offset_rad=" + number_text(o.abz->offset_rad));
        } else {
            q.push_back("interpolation=0");  // the a/b lines are not read
        }
    }
    for (std::size_t i = 0; i < q.size(); ++i) uri += (i ? "&" : "?") + q[i];
    sc.device = uri;
    // Without truth the error is measured against the estimator's own self-referenced phase.
    if (!truth || o.self_reference) sc.scoring.self_reference = true;
    sc.interface = o.interface;

    p.facts = {{"path", o.capture_path}, {"samples", n}, {"sample_rate_hz", fs}, {"has_truth", truth},
               {"encoder_source", o.encoder ? "profile file" : (from_capture ? "capture metadata" : "none")}};
    if (!truth_enc)
        p.facts["no_encoder"] = "neither an encoder profile nor the capture's metadata gives one: the estimator is told none, the errors have "
                                "no arcsec (they need lines_per_rev) and no bounds (they need the signal model)";
    const bool self_ref = sc.scoring.self_reference;
    p.run = plan_run(std::move(sc));
    if (self_ref)
        if (auto f = self_reference_motion_check(scan, o.settle_s)) p.run.warnings.push_back(std::move(*f));
    return p;
}

RunReport run_capture(const CaptureRunOptions& o) {
    CapturePlan p = plan_capture_run(o);
    std::optional<EstimatesWriter> out;
    if (!o.estimates_path.empty()) out.emplace(o.estimates_path);
    std::uint64_t samples = 0, valid = 0;
    RunOptions ro;
    ro.block = o.block;
    if (o.progress) ro.progress = [&](std::uint64_t done, std::uint64_t) { o.progress(done); };
    // The estimator's output as it left it: the estimates file, and how much of it it vouched for.
    ro.estimates = [&](std::size_t n, const double* t, const double* th, const double* om, const std::uint8_t* v) {
        if (out) out->write(n, t, th, om, v);
        samples += n;
        valid += static_cast<std::uint64_t>(std::count(v, v + n, std::uint8_t{1}));
    };
    double estimator_s = 0;
    ro.estimator_s = &estimator_s;
    RunReport r = execute_run(std::move(p.run), ro);
    if (out) out->close();
    json facts = p.facts;
    facts["estimates"] = {{"samples", samples}, {"valid_samples", valid},
                          {"valid_fraction", samples > 0 ? json(static_cast<double>(valid) / static_cast<double>(samples)) : json()}};
    facts["timing"] = {{"estimator_s", estimator_s},
                       {"estimator_samples_per_s", estimator_s > 0 ? static_cast<double>(samples) / estimator_s : 0.0}};
    facts["not_scored"] = nullptr;
    if (!p.has_truth && r.status == RunStatus::Done) {
        // Nothing could be scored, by design: no verdict rather than the evidence checks' FAIL,
        // and no warning about scores that do not exist (ekf-auto's learning, from a motion
        // the capture does not state).
        // The signals' grades against an interface profile need no truth: they stay, and are
        // the verdict (the signals', said so); the estimator's self-referenced error has no limit.
        json graded = json::array();
        for (const auto& m : r.measurements)
            if (m.value("estimator", "") == "run" && m.contains("interface")) graded.push_back(m);
        r.measurements = std::move(graded);
        if (r.measurements.empty()) {
            facts["not_scored"] = "the capture has no theta_true column: estimates only; nothing was scored, so the run has no verdict";
            r.verdict.reset();
        } else {
            facts["not_scored"] = "the capture has no theta_true column: the estimator's error is self-referenced and has no limit; the verdict "
                                  "grades the signals against the interface profile only";
            Verdict v = Verdict::Pass;
            for (const auto& m : r.measurements) {
                const std::string outcome = m.value("outcome", "");
                if (outcome == "FAIL") v = Verdict::Fail;
                else if (outcome == "MARGINAL" && v == Verdict::Pass) v = Verdict::Marginal;
            }
            r.verdict = v;
        }
        std::erase_if(r.warnings, [](const Finding& w) { return w.code == "scores_learning"; });
    }
    r.capture = std::move(facts);
    return r;
}

}  // namespace fringe
