#include "server/engine/evaluate.hpp"

#include "server/analysis/bounds.hpp"
#include "drivers/capture_file.hpp"
#include "estimator/estimator.hpp"
#include "server/analysis/scoring.hpp"
#include "signal_gen/fastmath.hpp"

#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace fringe {

using nlohmann::json;

EstimatesWriter::EstimatesWriter(const std::string& path) : path_(path) {
    f_ = std::fopen(path.c_str(), "w");
    if (!f_) throw CaptureError(path + ": cannot write: " + std::strerror(errno));
    std::fputs("t,theta_rad,omega_rad_s,valid\n", f_);
}

void EstimatesWriter::write(std::size_t n, const double* t, const double* th, const double* om, const std::uint8_t* v) {
    buf_.resize(n * 80);
    char* p = buf_.data();
    for (std::size_t i = 0; i < n; ++i) {
        p = std::to_chars(p, p + 32, t[i]).ptr; *p++ = ',';
        p = std::to_chars(p, p + 32, th[i]).ptr; *p++ = ',';
        p = std::to_chars(p, p + 32, om[i]).ptr; *p++ = ',';
        *p++ = v[i] ? '1' : '0'; *p++ = '\n';
    }
    const std::size_t len = static_cast<std::size_t>(p - buf_.data());
    if (std::fwrite(buf_.data(), 1, len, f_) != len) throw CaptureError(path_ + ": write failed: " + std::strerror(errno));
}

void EstimatesWriter::close() {
    if (f_) {
        const bool bad = std::fclose(f_) != 0;
        f_ = nullptr;
        if (bad) throw CaptureError(path_ + ": close failed");
    }
}

json evaluate_capture(const EvaluateOptions& o) {
    CaptureReader reader(o.capture_path, o.capture);
    CaptureData d;
    // A CSV without a sidecar gives its rate from the first time stamps: read a block first.
    bool more = reader.read(o.block, d);
    const double fs = reader.sample_rate_hz();
    if (!(fs > 0)) throw CaptureError(o.capture_path + ": sample rate unknown (no sidecar and fewer than two time stamps)");
    std::optional<EncoderProfile> from_capture;
    if (reader.meta().is_object() && reader.meta().contains("encoder"))
        from_capture = encoder_from_json(reader.meta()["encoder"], "capture.encoder");
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = fs;
    cfg.encoder = o.encoder ? o.encoder : from_capture;
    cfg.params = o.params.is_null() ? json::object() : o.params;
    auto estimator = est::make(o.estimator, cfg);

    const bool truth = reader.columns().theta_true;
    std::optional<AbzDecoder> abz;
    if (o.abz) {
        if (!reader.columns().abz())
            throw ConfigError("dut_interpolation", "the capture has no a/b lines to read a DUT's position from (docs/abz.md)");
        try {
            abz.emplace(*o.abz);
        } catch (const std::invalid_argument& e) {
            throw ConfigError("dut_interpolation", e.what());
        }
    }
    Scorer dut_scorer(ScoringOptions{o.settle_s, 0.1, o.max_harmonic});
    std::vector<double> dut_th;
    std::vector<std::uint8_t> dut_valid;
    std::optional<EstimatesWriter> out;
    if (!o.estimates_path.empty()) out.emplace(o.estimates_path);
    Scorer scorer(ScoringOptions{o.settle_s, 0.1, o.max_harmonic});
    ConventionCheck conventions;
    std::vector<double> th, om;
    std::vector<std::uint8_t> valid;
    std::uint64_t total = 0, valid_total = 0;
    // electrical radians of truth travelled during the settle time (distance, not net: a swing
    // teaches ekf-auto on every pass), for the scores_learning warning
    double settle_travel_rad = 0, t_first = 0, th_prev = 0;
    const auto t0 = std::chrono::steady_clock::now();
    double est_seconds = 0;
    for (; more; more = reader.read(o.block, d)) {
        const std::size_t n = d.size();
        th.resize(n); om.resize(n); valid.resize(n);
        const auto a = std::chrono::steady_clock::now();
        estimator->process({d.sin_v, d.cos_v}, {th, om, valid});
        est_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - a).count();
        if (out) out->write(n, d.t_s.data(), th.data(), om.data(), valid.data());
        valid_total += static_cast<std::uint64_t>(std::count(valid.begin(), valid.end(), std::uint8_t{1}));
        if (truth) {
            scorer.add(n, d.t_s.data(), d.theta_true_rad.data(),
                       d.omega_true_rad_s.empty() ? nullptr : d.omega_true_rad_s.data(), th.data(), om.data(), valid.data());
            conventions.add(n, d.theta_true_rad.data(), th.data(), valid.data());
            if (total == 0 && n > 0) { t_first = d.t_s[0]; th_prev = d.theta_true_rad[0]; }
            for (std::size_t i = 0; i < n && d.t_s[i] - t_first < o.settle_s; ++i) {
                settle_travel_rad += std::fabs(d.theta_true_rad[i] - th_prev);
                th_prev = d.theta_true_rad[i];
            }
        }
        if (abz) {
            dut_th.resize(n);
            dut_valid.resize(n);
            abz->process(n, d.t_s.data(), d.a.data(), d.b.data(), d.z.empty() ? nullptr : d.z.data(),
                         truth ? d.theta_true_rad.data() : nullptr, dut_th.data());
            for (std::size_t i = 0; i < n; ++i) dut_valid[i] = std::isfinite(dut_th[i]);
            if (truth)
                dut_scorer.add(n, d.t_s.data(), d.theta_true_rad.data(), d.omega_true_rad_s.empty() ? nullptr : d.omega_true_rad_s.data(),
                               dut_th.data(), nullptr, dut_valid.data());
        }
        total += n;
        if (o.progress) o.progress(total);
    }
    estimator->finish();
    if (out) out->close();
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

    json r;
    r["schema"] = "fringe.estimate";
    r["schema_version"] = 1;
    r["capture"] = {{"path", o.capture_path}, {"samples", total}, {"sample_rate_hz", fs}, {"has_truth", truth}};
    r["estimator"] = {{"name", o.estimator}, {"params", cfg.params}, {"state", estimator->state()}};
    // With or without truth: how much of the output the estimator vouched for.
    r["estimates"] = {{"samples", total}, {"valid_samples", valid_total},
                      {"valid_fraction", total > 0 ? json(static_cast<double>(valid_total) / static_cast<double>(total)) : json()}};
    r["encoder_source"] = o.encoder ? "profile file" : (from_capture ? "capture metadata" : "none");
    r["timing"] = {{"estimator_s", est_seconds}, {"wall_s", wall},
                   {"estimator_samples_per_s", est_seconds > 0 ? static_cast<double>(total) / est_seconds : 0.0}};
    if (abz) {
        const std::optional<EncoderProfile>& enc = from_capture ? from_capture : o.encoder;
        r["dut"] = {{"readout", abz->to_json()},
                    {"metrics", truth ? to_json(dut_scorer.finish(), enc ? enc->lines_per_rev : 0) : json()}};
    }
    if (!truth) {
        r["metrics"] = nullptr;
        r["note"] = "the capture has no theta_true column: estimates only, no scores";
        return r;
    }
    const ErrorMetrics m = scorer.finish();
    // Truth for units and bounds: the capture's own encoder, else the profile given.
    const std::optional<EncoderProfile>& truth_enc = from_capture ? from_capture : o.encoder;
    const int lines = truth_enc ? truth_enc->lines_per_rev : 0;
    r["settle_s"] = o.settle_s;
    r["metrics"] = to_json(m, lines);
    if (m.scored == 0) {
        r["note"] = "no scored samples: " + std::to_string(total) + " samples (" + std::to_string(static_cast<double>(total) / fs).substr(0, 8) +
                    " s), " + std::to_string(m.after_settle) + " after the " + std::to_string(o.settle_s).substr(0, 6) + " s settle time, " +
                    std::to_string(m.invalid_after_settle) + " of them marked invalid by the estimator";
    }
    json diag = json::array();
    const auto findings = conventions.findings();
    r["metrics"]["convention_violations"] = findings.size();
    for (const auto& f : findings) diag.push_back({{"code", f.code}, {"message", f.message}});
    const auto fmt3 = [](double x) { char b[32]; std::snprintf(b, sizeof b, "%.3g", x); return std::string(b); };
    if (m.after_settle > 0 && m.scored > 0) {
        const double vf = static_cast<double>(m.scored) / static_cast<double>(m.after_settle);
        if (vf < 0.95)  // a run's scoring.min_valid_fraction
            diag.push_back({{"code", "low_valid_fraction"},
                            {"message", "only " + fmt3(100.0 * vf) + " % of the " + std::to_string(m.after_settle) +
                                            " samples after the settle time are valid (a run needs 95 %): the figures describe those " +
                                            std::to_string(m.scored) + " samples only, not the capture"}});
    }
    if (o.estimator == "ekf-auto") {
        const json st = r["estimator"]["state"];
        const bool told = st.is_object() && st.value("told_profile", false);
        const double cycles = settle_travel_rad / kTwoPi;
        if (!told && m.scored > 0 && cycles < 50)
            diag.push_back({{"code", "scores_learning"},
                            {"message", "ekf-auto learns the waveform shape over about 50 electrical cycles of motion; the settle time of " +
                                            fmt3(o.settle_s) + " s covers " + fmt3(cycles) +
                                            " electrical cycles of travel, so the score includes its learning (raise --settle-s)"}});
    }
    if (truth_enc && m.scored > 0) {
        r["bounds"] = bounds_json(*truth_enc, *estimator, fs, m.scored, m.rms_rad);
        if (r["bounds"].value("efficiency_not_credible", json()).is_string())
            diag.push_back({{"code", "efficiency_not_credible"}, {"message", r["bounds"]["efficiency_not_credible"]}});
    } else {
        r["bounds"] = nullptr;
    }
    r["diagnosis"] = diag;
    return r;
}

}  // namespace fringe
