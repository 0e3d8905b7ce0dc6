#include "run.hpp"

#include "bounds.hpp"
#include "drivers/capture_file.hpp"
#include "drivers/device.hpp"
#include "estimator/estimator.hpp"
#include "scoring.hpp"
#include "spectrum.hpp"
#include "traces.hpp"
#include "signal_gen/config.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/generator.hpp"

#include <chrono>
#include <cmath>
#include <ctime>
#include <deque>
#include <limits>
#include <random>

#ifndef FRINGE_VERSION
#define FRINGE_VERSION "dev"
#endif

namespace fringe {

using nlohmann::json;

const std::vector<MetricInfo>& metric_catalog() {
    static const std::vector<MetricInfo> m = [] {
        std::vector<MetricInfo> v = {
            {"rms_rad", "rad", "rms phase error (electrical)"},
            {"std_rad", "rad", "phase error standard deviation"},
            {"mean_rad", "rad", "mean phase error"},
            {"max_abs_rad", "rad", "largest |error|"},
            {"max_dev_rad", "rad", "largest |error - mean|"},
            {"rms_percent_period", "%", "rms error in % of a signal period"},
            {"rms_arcsec_mech", "arcsec", "rms error, mechanical arcseconds"},
            {"max_abs_arcsec_mech", "arcsec", "largest |error|, mechanical arcseconds"},
            {"slipped_samples", "samples", "samples off by more than pi (cycle slips)"},
            {"invalid_after_settle", "samples", "samples flagged invalid after the settle time"},
            {"omega_error_std_rad_s", "rad/s", "rate error standard deviation"},
            {"lock_time_s", "s", "time until the error stays within 0.1 rad"},
            {"efficiency", "", "bound variance / mean squared error"},
        };
        for (int k = 1; k <= Scorer::kHarmonics; ++k)
            v.push_back({"harmonic_" + std::to_string(k) + "x_rad", "rad", std::to_string(k) + "x harmonic of the error"});
        return v;
    }();
    return m;
}

const MetricInfo* find_metric(const std::string& name) {
    for (const auto& m : metric_catalog())
        if (m.name == name) return &m;
    return nullptr;
}

namespace {

}  // namespace

std::optional<double> metric_value(const std::string& name, const json& metrics, const json& bounds) {
    auto num = [](const json& j) -> std::optional<double> { return j.is_number() ? std::optional(j.get<double>()) : std::nullopt; };
    if (name == "rms_rad") return num(metrics["rms"]["rad"]);
    if (name == "std_rad") return num(metrics["std"]["rad"]);
    if (name == "mean_rad") return num(metrics["mean"]["rad"]);
    if (name == "max_abs_rad") return num(metrics["max_abs"]["rad"]);
    if (name == "max_dev_rad") return num(metrics["max_dev"]["rad"]);
    if (name == "rms_percent_period") return num(metrics["rms"]["percent_period"]);
    if (name == "rms_arcsec_mech") return num(metrics["rms"]["arcsec_mech"]);
    if (name == "max_abs_arcsec_mech") return num(metrics["max_abs"]["arcsec_mech"]);
    if (name == "slipped_samples") return num(metrics["slipped_samples"]);
    if (name == "invalid_after_settle") return num(metrics["invalid_after_settle"]);
    if (name == "omega_error_std_rad_s") return metrics.contains("omega_error") ? num(metrics["omega_error"]["std_rad_s"]) : std::nullopt;
    if (name == "lock_time_s") return num(metrics["lock_time_s"]);
    if (name == "efficiency") return bounds.is_object() && bounds.contains("efficiency") ? num(bounds["efficiency"]) : std::nullopt;
    if (name.rfind("harmonic_", 0) == 0) {
        const int k = std::atoi(name.c_str() + 9);
        for (const auto& h : metrics["harmonics"])
            if (h["order"] == k) return num(h["amplitude"]["rad"]);
    }
    return std::nullopt;
}

std::string iso_now() {
    const auto t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    std::tm tm{};
    gmtime_r(&t, &tm);
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
    return buf;
}

namespace {

struct Lane {  // one estimator under test
    const EstimatorSpec* spec;
    std::unique_ptr<est::Estimator> e;
    Scorer scorer;
    std::vector<double> th, om;
    std::vector<std::uint8_t> valid;
    std::vector<double> err;              // theta_hat - theta_true, NaN where invalid (traces)
    std::vector<double> err_wrapped;      // scored error for the spectrum
    std::vector<std::uint8_t> scored;     // valid and after the settle time
    std::unique_ptr<ErrorSpectrum> spectrum;
    explicit Lane(const EstimatorSpec* s, double settle) : spec(s), scorer(settle) {}
};

}  // namespace

std::string new_run_id() {
    const auto t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    std::tm tm{};
    gmtime_r(&t, &tm);
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y%m%dT%H%M%SZ", &tm);
    std::random_device rd;
    char tail[12];
    std::snprintf(tail, sizeof tail, "%08x", static_cast<unsigned>(rd()));
    return std::string(buf) + "-" + tail;
}

void validate_run(const Scenario& sc) {
    if (sc.estimators.empty()) throw ConfigError("estimators", "a run needs at least one estimator under test");
    for (std::size_t i = 0; i < sc.estimators.size(); ++i) {
        const auto& spec = sc.estimators[i];
        est::EstimatorConfig cfg;
        cfg.sample_rate_hz = sc.sample_rate_hz;
        cfg.encoder = spec.encoder ? spec.encoder : std::optional(sc.encoder);
        cfg.params = spec.params;
        try {
            const auto& info = est::find(spec.name);
            resolve_params(info.params, spec.params);  // cheap checks first; external is not started here
            if (spec.name != "external") est::make(spec.name, cfg);
        } catch (const ConfigError& e) {
            throw e.prefixed("estimators[" + std::to_string(i) + "]");
        }
    }
    for (std::size_t i = 0; i < sc.limits.size(); ++i) {
        const auto& l = sc.limits[i];
        const std::string path = "limits[" + std::to_string(i) + "]";
        if (!find_metric(l.metric)) {
            std::string known;
            for (const auto& m : metric_catalog()) known += (known.empty() ? "" : ", ") + m.name;
            throw ConfigError(path + ".metric", "unknown metric '" + l.metric + "' (known: " + known + ")");
        }
        if (l.estimator != "*") {
            bool found = false;
            for (const auto& e : sc.estimators) found |= e.label == l.estimator;
            found |= l.estimator == "dut";  // a DUT board's own position (step mode)
            if (!found) throw ConfigError(path + ".estimator", "no estimator labelled '" + l.estimator + "' in this scenario");
        }
    }
}

json unstarted_report(const Scenario& sc, const std::string& id, const std::string& started_at, const std::string& status,
                      const std::string& verdict, const std::string& error) {
    return json{{"schema", "fringe.report"}, {"schema_version", 1}, {"fringe_version", FRINGE_VERSION}, {"id", id},
                {"started_at", started_at}, {"finished_at", iso_now()}, {"wall_s", 0.0}, {"scenario", sc}, {"seed", sc.seed},
                {"device", nullptr}, {"status", status}, {"verdict", verdict}, {"error", error},
                {"samples", {{"planned", sc.samples()}, {"processed", 0}}}, {"estimators", json::array()},
                {"measurements", json::array()}, {"traces", json::object()}};
}

json execute_run(const Scenario& sc, const RunOptions& o) {
    validate_run(sc);
    json report;
    report["schema"] = "fringe.report";
    report["schema_version"] = 1;
    report["fringe_version"] = FRINGE_VERSION;
    report["id"] = o.run_id.empty() ? new_run_id() : o.run_id;
    report["started_at"] = iso_now();
    report["scenario"] = sc;
    report["seed"] = sc.seed;
    std::string status = "done", error;
    const auto wall0 = std::chrono::steady_clock::now();

    std::vector<std::unique_ptr<Lane>> lanes;
    std::unique_ptr<dev::Device> device;
    dev::DeviceInfo dinfo;
    const std::uint64_t total = sc.samples();
    std::uint64_t processed = 0;
    // Traces: per-bucket envelopes and angle folds at the full rate (never stride samples).
    std::optional<TraceRecorder> traces;
    const double settle_end_s = sc.t0_s + sc.settle_s;
    // Electrical frequency for the spectrum's segment length (constant motion), and the mean true
    // rate over scored samples for its order axis.
    const double plan_fe_hz = sc.motion.kind == MotionKind::Constant
                                  ? std::fabs(sc.motion.velocity_rad_s) * sc.encoder.lines_per_rev / kTwoPi : 0.0;
    double sum_abs_omega = 0;
    std::uint64_t n_omega = 0;
    try {
        device = dev::open(sc.device);
        dinfo = device->info();
        report["device"] = dinfo;
        for (const auto& spec : sc.estimators) {
            auto lane = std::make_unique<Lane>(&spec, sc.settle_s);
            est::EstimatorConfig cfg;
            cfg.sample_rate_hz = sc.sample_rate_hz;
            cfg.encoder = spec.encoder ? spec.encoder : std::optional(sc.encoder);
            cfg.params = spec.params;
            lane->e = est::make(spec.name, cfg);
            lanes.push_back(std::move(lane));
        }
        // A board that reports its own interpolated position is scored like an estimator, "dut".
        static const EstimatorSpec dut_spec{"dut", "dut", nlohmann::json::object(), std::nullopt};
        if (dinfo.dut_position) lanes.push_back(std::make_unique<Lane>(&dut_spec, sc.settle_s));
        {
            std::vector<std::string> labels;
            const auto scored_plan = static_cast<std::uint64_t>(std::max(0.0, static_cast<double>(total) - sc.settle_s * sc.sample_rate_hz));
            const std::size_t seg = ErrorSpectrum::choose_segment(sc.sample_rate_hz, plan_fe_hz, scored_plan);
            for (auto& lane : lanes) {
                labels.push_back(lane->spec->label);
                lane->spectrum = std::make_unique<ErrorSpectrum>(sc.sample_rate_hz, seg);
            }
            traces.emplace(total, o.trace_points, labels, settle_end_s);
        }
        // Step mode (Modbus boards): one static pair per sample, settle, read back.
        const bool step_mode = !dinfo.streaming && dinfo.step_mode;
        std::vector<double> dut_th;
        Generator gen(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed, sc.t0_s);
        std::optional<CaptureWriter> recorder;
        if (!o.record_path.empty()) {
            json meta{{"sample_rate_hz", sc.sample_rate_hz}, {"t0_s", sc.t0_s}, {"encoder", sc.encoder}, {"scenario", sc},
                      {"device", dinfo}, {"board_id", dinfo.board_id}, {"run_id", report["id"]},
                      {"note", "device input recorded by fringe run; theta_true aligned for the device latency (0 where unknown)"}};
            recorder.emplace(o.record_path, CaptureColumns{true, true, false}, meta);
        }
        CaptureData rec;
        if (!step_mode) device->start(sc.sample_rate_hz);
        // Truth for each input frame: the generated sample latency_samples earlier. The first
        // latency_samples input frames predate the signal and are not scored.
        struct Truth { double t, th, om; bool known; };
        std::deque<Truth> pending;
        for (int k = 0; k < dinfo.latency_samples; ++k) pending.push_back({sc.t0_s + k / sc.sample_rate_hz, 0, 0, false});
        Block b;
        std::vector<double> in_s, in_c, t_s, th_true, om_true;
        std::vector<std::uint8_t> known;
        std::uint64_t k_out = 0;  // samples generated and written so far
        for (std::uint64_t k = 0; k < total;) {
            if (o.cancel && o.cancel->load()) { status = "aborted"; error = "cancelled"; break; }
            const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(step_mode ? 16 : o.block, total - k));
            std::size_t m = 0;
            bool eof = false;
            if (step_mode) {
                b.resize(n, sc.encoder.index.enabled);
                gen.generate(k, b);
                in_s.resize(n); in_c.resize(n); t_s.resize(n); th_true.resize(n); om_true.resize(n); known.resize(n); dut_th.resize(n);
                for (std::size_t i = 0; i < n; ++i) {
                    const dev::StepResult r = device->step(b.sin_v[i], b.cos_v[i], -1.0, 0);  // the device's settle and averaging
                    in_s[i] = r.sin_v; in_c[i] = r.cos_v;
                    dut_th[i] = r.dut_theta_rad ? *r.dut_theta_rad : std::numeric_limits<double>::quiet_NaN();
                    t_s[i] = b.t_s[i]; th_true[i] = b.theta_rad[i]; om_true[i] = b.omega_rad_s[i]; known[i] = 1;
                }
                m = n;
            } else {
            std::size_t want = n;
            // Output runs up to four blocks ahead of input: a real-time board (USB) must never run dry
            // while the host reads. Truth is queued as it is written.
            while (dinfo.needs_output && k_out < std::min<std::uint64_t>(total, k + 4 * o.block)) {
                const std::size_t nw = static_cast<std::size_t>(std::min<std::uint64_t>(o.block, total - k_out));
                b.resize(nw, sc.encoder.index.enabled);
                gen.generate(k_out, b);
                const auto w = device->write(b.sin_v, b.cos_v);
                if (w.status != dev::StreamStatus::Ok) {
                    status = "error";
                    error = std::string("output ") + dev::to_string(w.status) + " at sample " + std::to_string(k_out + w.frames) + ": " + w.message;
                    break;
                }
                for (std::size_t i = 0; i < nw; ++i) pending.push_back({b.t_s[i], b.theta_rad[i], b.omega_rad_s[i], true});
                k_out += nw;
                if (k_out == total) device->end_of_output();
            }
            if (status != "done") break;
            in_s.resize(want); in_c.resize(want); t_s.resize(want); th_true.resize(want); om_true.resize(want); known.resize(want);
            std::size_t got = 0;
            while (got < want) {
                const auto r = device->read(std::span(in_s).subspan(got), std::span(in_c).subspan(got), 1000);
                if (r.status == dev::StreamStatus::Overflow || r.dropped) {
                    status = "error";
                    error = "sample loss: " + std::to_string(r.dropped) + " input samples dropped before input sample " +
                            std::to_string(r.first_index) + " (" + r.message + ")";
                    break;
                }
                if (r.status != dev::StreamStatus::Ok) {
                    status = "error";
                    error = std::string("input ") + dev::to_string(r.status) + " at input sample " + std::to_string(k + got) + ": " + r.message;
                    break;
                }
                if (!dinfo.needs_output) {
                    if (r.frames == 0) { eof = true; break; }
                    std::vector<double> th(r.frames), om(r.frames);
                    const bool has = device->last_truth(th, om);
                    for (std::size_t i = 0; i < r.frames; ++i)
                        pending.push_back({sc.t0_s + static_cast<double>(k + got + i) / sc.sample_rate_hz, th[i], om[i], has});
                }
                if (r.frames == 0) {
                    status = "error";
                    error = "input underrun: the device returned no samples at input sample " + std::to_string(k + got);
                    break;
                }
                got += r.frames;
            }
            if (status != "done") break;
            m = got;
            for (std::size_t i = 0; i < m; ++i) {
                const Truth tr = pending.front();
                pending.pop_front();
                t_s[i] = tr.t; th_true[i] = tr.th; om_true[i] = tr.om; known[i] = tr.known;
            }
            }
            if (recorder) {
                rec.t_s.assign(t_s.begin(), t_s.begin() + static_cast<std::ptrdiff_t>(m));
                rec.sin_v.assign(in_s.begin(), in_s.begin() + static_cast<std::ptrdiff_t>(m));
                rec.cos_v.assign(in_c.begin(), in_c.begin() + static_cast<std::ptrdiff_t>(m));
                rec.theta_true_rad.assign(th_true.begin(), th_true.begin() + static_cast<std::ptrdiff_t>(m));
                rec.omega_true_rad_s.assign(om_true.begin(), om_true.begin() + static_cast<std::ptrdiff_t>(m));
                recorder->write(rec);
            }
            for (auto& lane : lanes) {
                lane->th.resize(m); lane->om.resize(m); lane->valid.resize(m);
                if (!lane->e) {  // the DUT's own position: no rate
                    for (std::size_t i = 0; i < m; ++i) {
                        lane->th[i] = dut_th[i];
                        lane->om[i] = std::numeric_limits<double>::quiet_NaN();
                        lane->valid[i] = std::isfinite(dut_th[i]) && known[i];
                    }
                    lane->scorer.add(m, t_s.data(), th_true.data(), om_true.data(), lane->th.data(), nullptr, lane->valid.data());
                    continue;
                }
                lane->e->process({std::span(in_s).first(m), std::span(in_c).first(m)},
                                 {std::span(lane->th), std::span(lane->om), std::span(lane->valid)});
                for (std::size_t i = 0; i < m; ++i) lane->valid[i] = lane->valid[i] && known[i];
                lane->scorer.add(m, t_s.data(), th_true.data(), om_true.data(), lane->th.data(), lane->om.data(), lane->valid.data());
            }
            std::vector<const double*> errs;
            for (auto& lane : lanes) {
                lane->err.resize(m); lane->err_wrapped.resize(m); lane->scored.resize(m);
                for (std::size_t i = 0; i < m; ++i) {
                    const double e = lane->th[i] - th_true[i];
                    const bool v = lane->valid[i] && std::isfinite(e);
                    lane->err[i] = v ? e : std::numeric_limits<double>::quiet_NaN();
                    lane->scored[i] = v && t_s[i] >= settle_end_s;
                    lane->err_wrapped[i] = v ? e - kTwoPi * std::floor(e * (1 / kTwoPi) + 0.5) : 0.0;  // wrapped, cheaply
                }
                lane->spectrum->add(m, lane->err_wrapped.data(), lane->scored.data());
                errs.push_back(lane->err.data());
            }
            for (std::size_t i = 0; i < m; ++i)
                if (known[i] && t_s[i] >= settle_end_s && std::isfinite(om_true[i])) { sum_abs_omega += std::fabs(om_true[i]); ++n_omega; }
            traces->add(m, t_s.data(), in_s.data(), in_c.data(), th_true.data(), known.data(), errs);
            k += m;
            processed = k;
            if (o.progress) o.progress(k, total);
            if (eof) break;
        }
        if (!step_mode) device->stop();
        if (recorder) recorder->close();
    } catch (const dev::DeviceError& e) {
        status = "error";
        error = e.what();
    } catch (const est::EstimatorError& e) {
        status = "error";
        error = e.what();
    } catch (const CaptureError& e) {
        status = "error";
        error = e.what();
    }
    if (!report.contains("device")) report["device"] = nullptr;

    // Scores, bounds, measurements
    const int lines = sc.encoder.lines_per_rev;
    json estimators = json::array(), measurements = json::array();
    std::string verdict = "PASS";
    for (auto& lane : lanes) {
        const ErrorMetrics m = lane->scorer.finish();
        json ej;
        ej["label"] = lane->spec->label;
        ej["name"] = lane->spec->name;
        ej["params"] = lane->spec->params;
        ej["state"] = lane->e ? lane->e->state() : json();
        ej["metrics"] = to_json(m, lines);
        ej["bounds"] = m.scored > 0 && lane->e ? bounds_json(sc.encoder, *lane->e, sc.sample_rate_hz, m.scored, m.rms_rad) : json();
        if (lane->spectrum) ej["spectrum"] = lane->spectrum->to_json(n_omega ? sum_abs_omega / static_cast<double>(n_omega) / kTwoPi : 0.0);
        estimators.push_back(ej);
    }
    for (const auto& l : sc.limits) {
        for (const auto& ej : estimators) {
            if (l.estimator != "*" && l.estimator != ej["label"]) continue;
            const MetricInfo* mi = find_metric(l.metric);
            const auto v = metric_value(l.metric, ej["metrics"], ej["bounds"]);
            json mj{{"estimator", ej["label"]}, {"metric", l.metric}, {"unit", mi->unit}, {"value", v ? json(*v) : json()}};
            json lim = json::object();
            if (l.max) lim["max"] = *l.max;
            if (l.min) lim["min"] = *l.min;
            lim["marginal_fraction"] = l.marginal_fraction;
            mj["limit"] = lim;
            std::string outcome = "PASS";
            if (!v || status != "done") outcome = status == "done" ? "FAIL" : "ERROR";  // a metric that could not be measured fails
            else {
                if (l.max && *v > *l.max) outcome = "FAIL";
                else if (l.min && *v < *l.min) outcome = "FAIL";
                else if (l.max && *v > *l.max - l.marginal_fraction * std::fabs(*l.max)) outcome = "MARGINAL";
                else if (l.min && *v < *l.min + l.marginal_fraction * std::fabs(*l.min)) outcome = "MARGINAL";
            }
            mj["outcome"] = outcome;
            if (outcome == "FAIL") verdict = "FAIL";
            else if (outcome == "MARGINAL" && verdict == "PASS") verdict = "MARGINAL";
            measurements.push_back(mj);
        }
    }
    if (status == "error") verdict = "ERROR";
    if (status == "aborted") verdict = "ABORTED";
    report["status"] = status;
    report["verdict"] = verdict;
    report["error"] = error.empty() ? json() : json(error);
    report["samples"] = {{"planned", total}, {"processed", processed}};
    report["estimators"] = estimators;
    report["measurements"] = measurements;
    report["traces"] = traces ? traces->to_json() : json::object();
    report["finished_at"] = iso_now();
    report["wall_s"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
    return report;
}

int exit_code(const json& report) {
    const std::string v = report.value("verdict", std::string("ERROR"));
    if (v == "PASS" || v == "MARGINAL") return 0;
    if (v == "FAIL") return 1;
    return 2;
}

}  // namespace fringe
