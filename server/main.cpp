// The fringe command line. Exit codes: 0 success/pass, 1 fail, 2 error.
#include "drivers/board_sim.hpp"
#include "drivers/capture_file.hpp"
#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "estimator/estimator.hpp"
#include "server/evaluate.hpp"
#include "server/http_server.hpp"
#include "server/instance_lock.hpp"
#include "server/remote.hpp"
#include "server/service.hpp"
#include "server/report_formats.hpp"
#include "server/run.hpp"
#include "server/store.hpp"
#include "server/verdict.hpp"
#include "server/sweep.hpp"
#include "server/scenario.hpp"
#include "server/text.hpp"
#include "signal_gen/analysis.hpp"
#include "signal_gen/config.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/generator.hpp"

#ifdef FRINGE_WITH_USB_EMULATOR
#include "drivers/usb_emulator.hpp"
#include <cstring>
#endif

#include <CLI/CLI.hpp>
#include <spdlog/pattern_formatter.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <csignal>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <thread>
#include <sys/stat.h>
#include <unistd.h>

namespace {

using namespace fringe;
using nlohmann::json;

constexpr int kExitOk = 0;
constexpr int kExitError = 2;

struct GenOptions {
    std::string scenario, output;
    std::int64_t samples = -1;
    std::int64_t seed = -1;
    std::size_t block = 65536;
    bool quiet = false;
};

// Fit the sin channel on theta_true over whole cycles and report what a bench user checks
// first: duty-cycle error (MODEL.md 2.3) and harmonic content.
json summarise(const std::vector<double>& sin_v, const std::vector<double>& theta) {
    json s = json::object();
    if (sin_v.size() < 16) return s;
    // Whole electrical cycles only, so the duty cycle is not biased by a partial cycle.
    const double span = std::fabs(theta.back() - theta.front());
    const double cycles = std::floor(span / kTwoPi);
    s["cycles"] = cycles;
    if (cycles < 1) return s;
    std::size_t n = sin_v.size();
    const double end_theta = theta.front() + std::copysign(cycles * kTwoPi, theta.back() - theta.front());
    while (n > 1 && std::fabs(theta[n - 1] - theta.front()) > std::fabs(end_theta - theta.front())) --n;
    const double duty = duty_cycle(sin_v.data(), n);
    HarmonicFit f = fit_harmonics(sin_v.data(), theta.data(), n, 4);
    s["duty_cycle"] = duty;
    s["duty_cycle_error_pct"] = 100.0 * (0.5 - duty);
    s["fundamental_v"] = f.amplitude[0];
    s["dc_v"] = f.dc;
    for (int k = 2; k <= 4; ++k) s["h" + std::to_string(k) + "_pct"] = 100.0 * f.amplitude[k - 1] / f.amplitude[0];
    return s;
}

int run_gen(const GenOptions& o) {
    Scenario sc = load_scenario(o.scenario);
    if (o.seed >= 0) sc.seed = static_cast<std::uint64_t>(o.seed);
    const std::uint64_t total = o.samples > 0 ? static_cast<std::uint64_t>(o.samples) : sc.samples();
    Generator gen(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed, sc.t0_s);
    json meta;
    meta["sample_rate_hz"] = sc.sample_rate_hz;
    meta["t0_s"] = sc.t0_s;
    meta["samples"] = total;
    meta["seed"] = sc.seed;
    meta["adc"] = sc.encoder.adc;
    meta["encoder"] = sc.encoder;
    meta["scenario"] = sc;
    meta["generator"] = "fringe " FRINGE_VERSION;
    CaptureColumns cols{true, true, sc.encoder.index.enabled};
    CaptureWriter w(o.output, cols, meta);

    const bool tty = isatty(STDERR_FILENO) && !o.quiet;
    Block b;
    std::vector<double> keep_s, keep_th;  // first 2^20 samples for the summary
    constexpr std::size_t kKeep = 1 << 20;
    auto t_start = std::chrono::steady_clock::now();
    auto t_last = t_start;
    for (std::uint64_t k = 0; k < total;) {
        const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(o.block, total - k));
        b.resize(n, cols.index);
        gen.generate(k, b);
        w.write(b);
        if (keep_s.size() < kKeep) {
            const std::size_t m = std::min(n, kKeep - keep_s.size());
            keep_s.insert(keep_s.end(), b.sin_v.begin(), b.sin_v.begin() + static_cast<std::ptrdiff_t>(m));
            keep_th.insert(keep_th.end(), b.theta_rad.begin(), b.theta_rad.begin() + static_cast<std::ptrdiff_t>(m));
        }
        k += n;
        auto now = std::chrono::steady_clock::now();
        if (tty && now - t_last > std::chrono::milliseconds(250)) {
            std::fprintf(stderr, "\rgen: %5.1f %% (%llu / %llu samples)", 100.0 * static_cast<double>(k) / static_cast<double>(total),
                         static_cast<unsigned long long>(k), static_cast<unsigned long long>(total));
            t_last = now;
        }
    }
    w.close();
    if (tty) std::fprintf(stderr, "\r%60s\r", "");
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
    json summary = summarise(keep_s, keep_th);
    if (!o.quiet) {
        std::printf("wrote %s: %llu samples, %.6g s at %.6g Hz, seed %llu (%.2f s)\n", o.output.c_str(),
                    static_cast<unsigned long long>(total), static_cast<double>(total) / sc.sample_rate_hz,
                    sc.sample_rate_hz, static_cast<unsigned long long>(sc.seed), secs);
        std::printf("encoder %s (%s), %d lines, kappa %.4f, fundamental %.4f V\n", sc.encoder.name.c_str(),
                    sc.encoder.model == ModelKind::Ideal ? "ideal" : "diffraction", sc.encoder.lines_per_rev,
                    sc.encoder.kappa_nominal(), sc.encoder.fundamental_amplitude_v());
        if (summary.contains("duty_cycle"))
            std::printf("sin channel over %.0f cycles: duty-cycle error %.2f %%, h2 %.2f %%, h3 %.3f %% of the fundamental %.4f V\n",
                        summary["cycles"].get<double>(), summary["duty_cycle_error_pct"].get<double>(),
                        summary["h2_pct"].get<double>(), summary["h3_pct"].get<double>(),
                        summary["fundamental_v"].get<double>());
    }
    return kExitOk;
}

struct EstimateOptions {
    std::string capture, estimator, encoder, output, report, channels;
    std::vector<std::string> params;
    int dut_interpolation = 0;  // 0: no ABZ readout
    long long dut_index_count = 0;
    double dut_offset_rad = 0;
    double settle_s = 0.1;
    bool list = false, json_list = false, quiet = false;
};

void print_estimators(bool as_json) {
    if (as_json) {
        std::printf("%s\n", json(est::registry()).dump(2).c_str());
        return;
    }
    for (const auto& e : est::registry()) {
        std::printf("%s\n  %s\n", e.name.c_str(), e.summary.c_str());
        for (const auto& p : e.params) {
            json pj = p;
            std::string range;
            if (pj.contains("min") || pj.contains("max"))
                range = " [" + (pj.contains("min") ? pj["min"].dump() : std::string("-inf")) + ", " +
                        (pj.contains("max") ? pj["max"].dump() : std::string("inf")) + "]";
            if (pj.contains("options")) {
                range = " {";
                for (const auto& opt : p.options) range += (range.size() > 2 ? "|" : "") + opt;
                range += "}";
            }
            std::printf("    %-22s %-8s %-8s default %-10s%s\n        %s\n", p.name.c_str(), pj["type"].get<std::string>().c_str(),
                        p.unit.empty() ? "-" : p.unit.c_str(), p.default_value.is_null() ? "derived" : p.default_value.dump().c_str(),
                        range.c_str(), p.description.c_str());
        }
    }
}

// Harmonic amplitudes with the share of the error power they hold, or why there are none.
void print_harmonics(const json& m) {
    const auto& ha = m["harmonic_analysis"];
    if (m["harmonics"].empty()) {
        if (ha["note"].is_string()) std::printf("harmonics: not reported: %s\n", ha["note"].get<std::string>().c_str());
        return;
    }
    std::printf("harmonics (rad):");
    for (const auto& h : m["harmonics"]) std::printf(" %dx %.2e", h["order"].get<int>(), h["amplitude"]["rad"].get<double>());
    std::printf("\n  1x..%dx hold %.1f %% of the error variance; broadband rest %.3e rad rms\n", static_cast<int>(m["harmonics"].size()),
                100.0 * ha["power_fraction"].get<double>(), ha["broadband_rms_rad"].get<double>());
    if (ha["note"].is_string()) std::printf("  (%s)\n", ha["note"].get<std::string>().c_str());
}

int run_estimate(const EstimateOptions& o) {
    if (o.list) {
        print_estimators(o.json_list);
        return kExitOk;
    }
    if (o.capture.empty()) throw ConfigError("capture", "a capture file is required (or --list)");
    if (o.estimator.empty()) throw ConfigError("estimator", "--estimator NAME is required (see --list)");
    if (o.output.empty() && o.report.empty()) throw ConfigError("output", "give -o ESTIMATES.csv and/or --report REPORT.json");
    EvaluateOptions e;
    e.capture_path = o.capture;
    e.estimator = o.estimator;
    e.params = est::parse_param_assignments(est::find(o.estimator).params, o.params);
    if (!o.encoder.empty()) e.encoder = load_encoder(o.encoder);
    e.settle_s = o.settle_s;
    e.estimates_path = o.output;
    if (!o.channels.empty()) e.capture.channels = parse_channel_map(o.channels);
    if (o.dut_interpolation > 0) e.abz = AbzConfig{o.dut_interpolation, o.dut_index_count, o.dut_offset_rad};
    const bool tty = isatty(STDERR_FILENO) && !o.quiet;
    auto last = std::chrono::steady_clock::now();
    if (tty)
        e.progress = [&](std::uint64_t done) {
            const auto now = std::chrono::steady_clock::now();
            if (now - last > std::chrono::milliseconds(250)) {
                std::fprintf(stderr, "\restimate: %llu samples", static_cast<unsigned long long>(done));
                last = now;
            }
        };
    const json r = evaluate_capture(e);
    if (tty) std::fprintf(stderr, "\r%60s\r", "");
    if (!o.report.empty()) {
        std::FILE* f = std::fopen(o.report.c_str(), "w");
        if (!f) throw std::runtime_error(o.report + ": cannot write report");
        const std::string text = r.dump(2, ' ', false, json::error_handler_t::replace) + "\n";
        const bool ok = std::fwrite(text.data(), 1, text.size(), f) == text.size();
        if (std::fclose(f) != 0 || !ok) throw std::runtime_error(o.report + ": write failed");
    }
    if (!o.quiet) {
        std::printf("%s on %s: %llu samples, %.3g M samples/s\n", o.estimator.c_str(), o.capture.c_str(),
                    static_cast<unsigned long long>(r["capture"]["samples"].get<std::uint64_t>()),
                    r["timing"]["estimator_samples_per_s"].get<double>() / 1e6);
        if (r["metrics"].is_null()) {
            std::printf("no theta_true in the capture: estimates only\n");
        } else if (r["metrics"]["scored"].get<std::uint64_t>() == 0) {
            std::printf("%s\n", r["note"].get<std::string>().c_str());
        } else {
            const auto& m = r["metrics"];
            const auto& ev = m["evidence"];
            std::printf("error after %.3g s settle (%llu samples, %.1f electrical cycles, valid %.1f %%): rms %.3e rad (%.4f %% of a period), std %.3e, mean %.3e, max|e| %.3e rad, slipped %llu\n",
                        o.settle_s, static_cast<unsigned long long>(m["scored"].get<std::uint64_t>()), ev["scored_cycles"].get<double>(),
                        100.0 * ev["valid_fraction"].get<double>(), m["rms"]["rad"].get<double>(),
                        m["rms"]["percent_period"].get<double>(), m["std"]["rad"].get<double>(), m["mean"]["rad"].get<double>(),
                        m["max_abs"]["rad"].get<double>(), static_cast<unsigned long long>(m["slipped_samples"].get<std::uint64_t>()));
            print_harmonics(m);
            // fringe estimate has no limits; say when a run would not have had enough evidence.
            if (m["scored"].get<std::uint64_t>() < 1000 || ev["scored_cycles"].get<double>() < 3)
                std::printf("warning: only %llu scored samples over %.2f electrical cycles: below a run's evidence minimum (1000 samples, 3 cycles); "
                            "treat these figures as indicative\n",
                            static_cast<unsigned long long>(m["scored"].get<std::uint64_t>()), ev["scored_cycles"].get<double>());
            const auto& b = r["bounds"];
            if (b.is_object() && b.contains("per_sample_crb_rad")) {
                std::printf("bounds: per-sample CRB %.3e rad", b["per_sample_crb_rad"].get<double>());
                if (b.contains("pcrb_rad")) std::printf(", PCRB %.3e rad (noise-only %.3e)", b["pcrb_rad"].get<double>(), b["pcrb_noise_only_rad"].get<double>());
                if (!b["efficiency"].is_null()) std::printf(", efficiency %.3f vs %s", b["efficiency"].get<double>(), b["efficiency_against"].get<std::string>().c_str());
                std::printf("\n");
            }
            for (const auto& d : r["diagnosis"]) std::printf("warning: %s\n", d["message"].get<std::string>().c_str());
        }
        if (r.contains("dut")) {
            const auto& ro = r["dut"]["readout"];
            const auto& m = r["dut"]["metrics"];
            std::printf("dut (ABZ, %d counts per cycle, reference %s): %llu edges, %llu illegal transitions, %llu index pulses (%llu off)",
                        ro["counts_per_cycle"].get<int>(), ro["reference"].get<std::string>().c_str(),
                        static_cast<unsigned long long>(ro["edges"].get<std::uint64_t>()),
                        static_cast<unsigned long long>(ro["illegal_transitions"].get<std::uint64_t>()),
                        static_cast<unsigned long long>(ro["index_pulses"].get<std::uint64_t>()),
                        static_cast<unsigned long long>(ro["index_errors"].get<std::uint64_t>()));
            if (m.is_object() && m["rms"].is_object())
                std::printf(", error rms %.3e rad, max|e| %.3e rad", m["rms"]["rad"].get<double>(), m["max_abs"]["rad"].get<double>());
            std::printf("\n");
        }
    }
    return kExitOk;
}

std::atomic<bool> g_cancel{false};
extern "C" void on_interrupt(int) { g_cancel.store(true); }

struct RunCliOptions {
    std::string scenario, report, junit, html, data, record, device, server, token_file;
    std::int64_t seed = -1;
    bool no_db = false, quiet = false;
};

void print_run_summary(const json& r, const std::string& name) {
    std::printf("run %s: %s %s (%s)\n", r["id"].get<std::string>().c_str(), name.c_str(), r["verdict"].get<std::string>().c_str(),
                r["status"].get<std::string>().c_str());
    if (r["error"].is_string()) std::printf("error: %s\n", r["error"].get<std::string>().c_str());
    for (const auto& w : r.value("warnings", json::array())) std::printf("warning: %s\n", w.value("message", "").c_str());
    for (const auto& e : r["estimators"]) {
        const auto& m = e["metrics"];
        const auto& ev = m.value("evidence", json::object());
        if (!m["rms"].is_object()) {
            std::printf("  %-20s no scored samples (%llu after the settle time, valid %s)\n", e["label"].get<std::string>().c_str(),
                        static_cast<unsigned long long>(ev.value("samples_after_settle", std::uint64_t{0})),
                        ev.value("valid_fraction", json()).is_number() ? (std::to_string(100.0 * ev["valid_fraction"].get<double>()).substr(0, 5) + " %").c_str() : "-");
            continue;
        }
        std::printf("  %-20s rms %.3e rad, max|e| %.3e rad, slipped %llu; scored %llu samples, %.1f cycles, valid %.1f %%\n",
                    e["label"].get<std::string>().c_str(), m["rms"]["rad"].get<double>(), m["max_abs"]["rad"].get<double>(),
                    static_cast<unsigned long long>(m["slipped_samples"].get<std::uint64_t>()),
                    static_cast<unsigned long long>(ev.value("scored_samples", std::uint64_t{0})), ev.value("scored_cycles", 0.0),
                    100.0 * ev.value("valid_fraction", 0.0));
    }
    // Counts as integers, everything else to 4 significant digits.
    auto fmt = [](const json& v) {
        if (!v.is_number()) return std::string("not measured");
        const double x = v.get<double>();
        char b[32];
        if (x == std::floor(x) && std::fabs(x) < 1e15) std::snprintf(b, sizeof b, "%.0f", x);
        else std::snprintf(b, sizeof b, "%.4g", x);
        return std::string(b);
    };
    for (const auto& m : r["measurements"]) {
        std::string lim;
        const auto& l = m["limit"];
        if (l.contains("min")) lim += ">= " + fmt(l["min"]);
        if (l.contains("max")) lim += std::string(lim.empty() ? "" : ", ") + "<= " + fmt(l["max"]);
        char val[32];
        std::snprintf(val, sizeof val, "%s", fmt(m["value"]).c_str());
        const std::string unit = m["value"].is_number() && !m["unit"].get<std::string>().empty() ? " " + m["unit"].get<std::string>() : "";
        std::printf("  %-8s %s %s = %s%s (limit %s%s)%s\n", m["outcome"].get<std::string>().c_str(), m["estimator"].get<std::string>().c_str(),
                    m["metric"].get<std::string>().c_str(), val, unit.c_str(), lim.c_str(),
                    m.value("implicit", false) ? ", evidence" : "", m.contains("reason") ? ("; " + m["reason"].get<std::string>()).c_str() : "");
    }
}

// fringe run --server URL: the scenario is read and checked here (file references inlined),
// run by the service, and its report fetched; same output files, summary and exit code.
int run_run_remote(const RunCliOptions& o, const Scenario& sc) {
    if (!o.record.empty()) throw ConfigError("record", "--record needs the device on this host; not with --server");
    if (!o.data.empty()) throw ConfigError("data", "the service keeps the history; --data does not apply with --server");
    if (sc.motion.kind == MotionKind::Table)
        throw ConfigError("motion.file", "a table motion is read from a file on the service's host; with --server, put the table in the service's fixtures and run a scenario there");
    const ServiceUrl url = parse_service_url(o.server);
    const std::string token_path = o.token_file.empty() ? default_data_dir() + "/token" : o.token_file;
    // No default token file: send none, and the service's 401 says what is missing.
    const std::string token = o.token_file.empty() && !std::filesystem::exists(token_path) ? "" : read_token_file(token_path);
    ServiceClient client(url, token);
    RemoteRunOptions ro;
    ro.junit = o.junit;
    ro.html = o.html;
    ro.cancel = &g_cancel;  // Ctrl-C cancels the run on the service; its report still comes back
    std::signal(SIGINT, on_interrupt);
    std::signal(SIGTERM, on_interrupt);
    const bool tty = isatty(STDERR_FILENO) && !o.quiet;
    if (tty)
        ro.progress = [](std::uint64_t done, std::uint64_t total) {
            if (total) std::fprintf(stderr, "\rrun: %5.1f %%", 100.0 * static_cast<double>(done) / static_cast<double>(total));
        };
    json r;
    std::string failure;
    try {
        r = run_remote(client, json(sc), ro);
    } catch (const RemoteError& e) {
        failure = e.what();
    }
    if (tty) std::fprintf(stderr, "\r%40s\r", "");
    if (!failure.empty()) {
        spdlog::error("{}", failure);
        return kExitError;
    }
    if (!o.report.empty()) write_file_atomic(o.report, r.dump(2, ' ', false, json::error_handler_t::replace) + "\n");
    if (!o.quiet) print_run_summary(r, sc.name);
    if (r["error"].is_string()) spdlog::error("{}", r["error"].get<std::string>());
    return exit_code(r);
}

int run_run(const RunCliOptions& o) {
    Scenario sc = load_scenario(o.scenario);
    if (o.seed >= 0) sc.seed = static_cast<std::uint64_t>(o.seed);
    if (!o.device.empty()) sc.device = o.device;
    validate_run(sc);  // preflight errors stop here (exit 2); warnings come back in the report
    if (!o.server.empty()) return run_run_remote(o, sc);
    // The run's row names this process's instance, whose lock we hold until the report is
    // stored: a service on the same folder sees the run alive, and interrupted once we are gone.
    InstanceLock instance;
    std::unique_ptr<RunStore> store;
    RunOptions ro;
    ro.run_id = new_run_id();
    ro.record_path = o.record;
    // Ctrl-C / SIGTERM: finish the block, end the run as ABORTED and keep its report.
    ro.cancel = &g_cancel;
    std::signal(SIGINT, on_interrupt);
    std::signal(SIGTERM, on_interrupt);
    if (!o.no_db) {
        const std::string dir = o.data.empty() ? default_data_dir() : o.data;
        instance.acquire_instance(dir, "cli-" + new_instance_id());
        store = std::make_unique<RunStore>(dir + "/runs.db", instance.id());
        store->begin(ro.run_id, iso_now(), sc.name, sc.dut);
    }
    const bool tty = isatty(STDERR_FILENO) && !o.quiet;
    auto last = std::chrono::steady_clock::now();
    if (tty)
        ro.progress = [&](std::uint64_t done, std::uint64_t total) {
            const auto now = std::chrono::steady_clock::now();
            if (now - last > std::chrono::milliseconds(250)) {
                std::fprintf(stderr, "\rrun: %5.1f %%", 100.0 * static_cast<double>(done) / static_cast<double>(total));
                last = now;
            }
        };
    json r;
    try {
        r = execute_run(sc, ro);
    } catch (const std::exception& e) {  // the history must not keep it "running"
        r = unstarted_report(sc, ro.run_id, iso_now(), "error", "ERROR", e.what());
    }
    if (tty) std::fprintf(stderr, "\r%40s\r", "");
    // The report survives first: files, then the history.
    if (!o.report.empty()) write_file_atomic(o.report, r.dump(2, ' ', false, json::error_handler_t::replace) + "\n");
    if (!o.junit.empty()) write_file_atomic(o.junit, junit_xml(r));
    if (!o.html.empty()) write_file_atomic(o.html, report_html(r));
    std::string store_error;
    if (store) {
        try {
            store->finish(r);
        } catch (const std::exception& e) {
            store_error = e.what();
        }
    }
    if (!o.quiet) print_run_summary(r, sc.name);
    if (r["status"] == "error") spdlog::error("{}", r["error"].get<std::string>());
    if (!store_error.empty()) {
        // A verdict that is not in the history is not a finished run: say so and fail.
        spdlog::error("the run's report could not be stored in the history: {}{}", store_error,
                      o.report.empty() ? "" : " (the report file " + o.report + " was written)");
        return kExitError;
    }
    return exit_code(r);
}

struct RunsOptions {
    std::string data, verdict, scenario, since, show;
    int limit = 20;
    bool as_json = false;
};

// --since: an ISO date or time (2026-11-21, 2026-11-21T15:00:00Z), "today", "yesterday" or
// "Nd" (N days ago), as the store's ISO UTC text; anything else is an error, not an empty list.
std::string parse_since(const std::string& v) {
    auto day_start = [](std::time_t t) {
        std::tm tm{};
        gmtime_r(&t, &tm);
        char b[32];
        std::strftime(b, sizeof b, "%Y-%m-%dT00:00:00Z", &tm);
        return std::string(b);
    };
    const std::time_t now = std::time(nullptr);
    if (v == "today") return day_start(now);
    if (v == "yesterday") return day_start(now - 86400);
    if (v.size() >= 2 && v.back() == 'd' && v.find_first_not_of("0123456789") == v.size() - 1)
        return day_start(now - 86400 * static_cast<std::time_t>(std::stoll(v.substr(0, v.size() - 1))));
    std::tm tm{};
    const char* end = strptime(v.c_str(), "%Y-%m-%d", &tm);
    if (end && *end == 0) return v + "T00:00:00Z";
    if (end && (*end == 'T' || *end == ' ')) {
        const char* e2 = strptime(end + 1, "%H:%M", &tm);
        if (e2 && *e2 == ':') e2 = strptime(e2 + 1, "%S", &tm);
        if (e2 && (*e2 == 0 || (e2[0] == 'Z' && e2[1] == 0))) {
            char b[32];
            std::strftime(b, sizeof b, "%Y-%m-%dT%H:%M:%SZ", &tm);
            return b;
        }
    }
    throw ConfigError("since", "expected a date or time in UTC (2026-11-21, 2026-11-21T15:00:00Z), today, yesterday or Nd (N days ago); got '" + v + "'");
}

int run_runs(const RunsOptions& o) {
    RunStore store((o.data.empty() ? default_data_dir() : o.data) + "/runs.db");
    if (!o.show.empty()) {
        auto r = store.report(o.show);
        if (!r) {
            if (store.row(o.show)) throw ConfigError("id", "run '" + o.show + "' has no report yet (it is queued or running, or ended without one)");
            throw ConfigError("id", "no run '" + o.show + "' in this history (fringe runs lists them)");
        }
        if (o.as_json) std::printf("%s\n", r->dump(2, ' ', false, json::error_handler_t::replace).c_str());
        else print_run_summary(*r, (*r)["scenario"].value("name", std::string("run")));
        return kExitOk;
    }
    RunFilter f{o.verdict, o.scenario, o.since, o.limit};
    if (!o.verdict.empty()) {
        const auto v = verdict_from(o.verdict);
        if (!v) throw ConfigError("verdict", "expected PASS, MARGINAL, FAIL, ERROR or ABORTED (any case); got '" + o.verdict + "'");
        f.verdict = to_string(*v);
    }
    if (!o.since.empty()) f.since = parse_since(o.since);
    const auto rows = store.list(f);
    if (o.as_json) {
        json a = json::array();
        for (const auto& r : rows)
            a.push_back({{"id", r.id}, {"created_at", r.created_at}, {"scenario", r.scenario}, {"dut", r.dut}, {"status", r.status}, {"verdict", r.verdict}});
        std::printf("%s\n", a.dump(2, ' ', false, json::error_handler_t::replace).c_str());
        return kExitOk;
    }
    // Columns as wide as their widest cell.
    std::vector<std::array<std::string, 6>> cells{{"id", "started", "scenario", "dut", "status", "verdict"}};
    for (const auto& r : rows) cells.push_back({r.id, r.created_at, r.scenario, r.dut, r.status, r.verdict});
    std::array<std::size_t, 6> w{};
    for (const auto& c : cells)
        for (std::size_t k = 0; k < 6; ++k) w[k] = std::max(w[k], c[k].size());
    for (const auto& c : cells) {
        std::string line;
        for (std::size_t k = 0; k < 6; ++k) line += c[k] + (k + 1 < 6 ? std::string(w[k] - c[k].size() + 2, ' ') : "");
        std::printf("%s\n", line.c_str());
    }
    if (rows.empty()) std::fprintf(stderr, "no runs match\n");
    return kExitOk;
}

struct SweepOptions {
    std::string sweep, csv, md;
    int jobs = 0;
    bool quiet = false;
};

int run_sweep_cli(const SweepOptions& o) {
    const Sweep s = load_sweep(o.sweep);
    const bool tty = isatty(STDERR_FILENO) && !o.quiet;
    const auto t0 = std::chrono::steady_clock::now();
    const auto res = run_sweep(s, o.jobs > 0 ? o.jobs : s.jobs, [&](std::size_t done, std::size_t total) {
        if (tty) std::fprintf(stderr, "\rsweep: %zu / %zu runs", done, total);
    });
    if (tty) std::fprintf(stderr, "\r%40s\r", "");
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!o.csv.empty()) write_file_atomic(o.csv, sweep_csv(s, res));
    const std::string md = sweep_markdown(s, res);
    if (!o.md.empty()) write_file_atomic(o.md, md);
    if (!o.quiet) std::printf("%s\n%zu runs in %.1f s\n", md.c_str(), res.size(), secs);
    for (const auto& r : res)
        if (r.status != "done") {
            spdlog::error("{}: {}", r.row.label, r.error);
            return kExitError;
        }
    return kExitOk;
}

struct BoardSimCli {
    dev::BoardSimOptions o;
    std::vector<std::string> params;
};

std::atomic<bool> g_sim_stop{false};
void on_sim_signal(int) { g_sim_stop = true; }

int run_board_sim_cli(BoardSimCli& c) {
    if (!c.params.empty()) {
        const auto& info = est::find(c.o.estimator);
        c.o.params = parse_param_assignments(info.params, c.params);
    }
    c.o.stop = &g_sim_stop;
    std::signal(SIGINT, on_sim_signal);
    std::signal(SIGTERM, on_sim_signal);
    c.o.on_listening = [&](const std::string& where) {
        std::printf("board-sim %s (%s) listening on %s\n", c.o.board.c_str(), c.o.estimator.c_str(), where.c_str());
        std::fflush(stdout);
    };
    const long long n = dev::run_board_sim(c.o);
    std::printf("board-sim: %lld requests answered%s\n", n, g_sim_stop ? "" : " (stopped by a fault option)");
    return kExitOk;
}

struct DevicesOptions {
    std::vector<std::string> probe;
    bool as_json = false;
};

int run_devices(const DevicesOptions& o) {
    json out{{"drivers", dev::drivers()}, {"boards", json::array()}, {"reachable", json::array()}};
    for (const auto& name : dev::board_names()) {
        try {
            const auto b = dev::load_board(name);
            out["boards"].push_back({{"name", b.name}, {"kind", b.kind}, {"description", b.description}, {"dut_position", b.has_dut_position()}});
        } catch (const std::exception& e) {
            out["boards"].push_back({{"name", name}, {"problem", e.what()}});
        }
    }
    out["reachable"].push_back({{"uri", "loopback:"}, {"ok", true}, {"description", "simulated converter chain"}});
    for (const auto& d : dev::drivers())
        if (d.find)
            for (auto found : d.find()) {
                found["ok"] = true;
                out["reachable"].push_back(found);
            }
    int rc = kExitOk;
    for (const auto& uri : o.probe) {
        try {
            auto d = dev::open(uri);
            out["reachable"].push_back({{"uri", uri}, {"ok", true}, {"info", d->info()}});
        } catch (const std::exception& e) {
            out["reachable"].push_back({{"uri", uri}, {"ok", false}, {"error", e.what()}});
            rc = kExitError;
        }
    }
    if (o.as_json) {
        std::printf("%s\n", out.dump(2).c_str());
        return rc;
    }
    std::printf("drivers:\n");
    for (const auto& d : dev::drivers()) {
        std::printf("  %-12s %s\n", d.scheme.c_str(), d.summary.c_str());
        for (const auto& p : d.settings) {
            json pj = p;
            std::printf("      %-16s %-8s default %s  %s\n", p.name.c_str(), p.unit.empty() ? "-" : p.unit.c_str(),
                        p.default_value.is_null() ? "derived" : p.default_value.dump().c_str(), p.description.c_str());
        }
    }
    std::printf("board profiles (%s):\n", dev::boards_dir().c_str());
    for (const auto& b : out["boards"])
        std::printf("  %-20s %s\n", b["name"].get<std::string>().c_str(), b.contains("problem") ? b["problem"].get<std::string>().c_str() : b["description"].get<std::string>().c_str());
    std::printf("reachable:\n");
    for (const auto& r : out["reachable"])
        std::printf("  %-40s %s\n", r["uri"].get<std::string>().c_str(),
                    r["ok"].get<bool>() ? (r.contains("info") ? r["info"]["board_id"].get<std::string>().c_str()
                                                             : r.contains("board_id") ? r["board_id"].get<std::string>().c_str() : "ok")
                                        : r["error"].get<std::string>().c_str());
    return rc;
}

struct ServeOptions {
    std::string bind = "127.0.0.1:8080", data, token_file, fixtures = FRINGE_SOURCE_DIR "/fixtures", web = FRINGE_SOURCE_DIR "/web";
    unsigned workers = 0, threads = 2;
    double max_upload_mb = 256, upload_quota_mb = 4096, max_report_mb = 64;
    double max_samples = 1e9;
    std::size_t max_estimators = 16, max_limits = 64;
    unsigned max_connections = 256;
    int body_timeout_s = 10;
    double upload_min_kib_s = 64;
    bool allow_external = false;
    std::vector<std::string> allow_device, allow_host;
};

// The service logs what requests carry (targets, scenario names, messages): one line per
// event, control characters escaped, so a request cannot forge or split log lines.
class EscapedPayload : public spdlog::custom_flag_formatter {
public:
    void format(const spdlog::details::log_msg& msg, const std::tm&, spdlog::memory_buf_t& dest) override {
        const std::string e = log_escape(std::string_view(msg.payload.data(), msg.payload.size()));
        dest.append(e.data(), e.data() + e.size());
    }
    std::unique_ptr<custom_flag_formatter> clone() const override { return std::make_unique<EscapedPayload>(); }
};

int run_serve(const ServeOptions& o) {
    auto formatter = std::make_unique<spdlog::pattern_formatter>();
    formatter->add_flag<EscapedPayload>('*').set_pattern("%^%l%$: %*");
    spdlog::default_logger()->set_formatter(std::move(formatter));
    // Everything the service creates (run store, uploads, locks) is for its user only, like the token.
    ::umask(077);
    ServiceConfig cfg;
    cfg.data_dir = o.data.empty() ? default_data_dir() : o.data;
    cfg.fixtures_dir = o.fixtures;
    cfg.web_dir = o.web;
    cfg.workers = o.workers ? o.workers : std::max(1u, std::thread::hardware_concurrency());
    cfg.max_upload_bytes = static_cast<std::uint64_t>(o.max_upload_mb * 1024 * 1024);
    cfg.allow_external = o.allow_external;
    cfg.allow_devices = o.allow_device;
    cfg.allow_hosts = o.allow_host;
    cfg.max_samples = o.max_samples;
    cfg.max_estimators = o.max_estimators;
    cfg.max_limits = o.max_limits;
    cfg.max_report_bytes = static_cast<std::size_t>(o.max_report_mb * 1024 * 1024);
    cfg.upload_quota_bytes = static_cast<std::uint64_t>(o.upload_quota_mb * 1024 * 1024);
    cfg.token_for_reads = !is_loopback_bind(o.bind);
    const std::string token_file = o.token_file.empty() ? cfg.data_dir + "/token" : o.token_file;
    bool created = false;
    cfg.token = load_or_create_token(token_file, &created);
    Service svc(cfg);
    HttpServerOptions ho;
    ho.bind = o.bind;
    ho.threads = o.threads;
    ho.max_connections = o.max_connections;
    ho.body_timeout_s = o.body_timeout_s;
    ho.upload_min_bytes_per_s = o.upload_min_kib_s * 1024;
    HttpServer server(svc, ho);
    std::printf("fringe %s serving %s (data %s, %u run workers)\n", FRINGE_VERSION, server.url().c_str(), cfg.data_dir.c_str(), cfg.workers);
    if (created)
        std::printf("API token (printed this once; stored in %s, mode 0600): %s\nopen %s#token=%s\n", token_file.c_str(), cfg.token.c_str(),
                    server.url().c_str(), cfg.token.c_str());
    else
        std::printf("API token: in %s (send Authorization: Bearer <token>; paste it into the UI once)\n", token_file.c_str());
    if (cfg.token_for_reads) std::printf("bound beyond loopback: every API request needs the token\n");
    std::string devices = "loopback:, uploaded captures";
    for (const auto& d : cfg.allow_devices) devices += ", " + d;
    std::printf("devices clients may use: %s (--allow-device adds more)\n", devices.c_str());
    std::fflush(stdout);
    server.run();
    std::printf("fringe serve: stopped\n");
    return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
#ifdef FRINGE_WITH_USB_EMULATOR
    // fringe-usb-sim: the fringe CLI with an emulated USB board in this process (umockdev;
    // options from $FRINGE_USB_EMULATOR, e.g. "drop_at=40,unplug_after=200"). umockdev's
    // preload must be there from the start: re-exec with it.
    if (const char* pre = std::getenv("LD_PRELOAD"); !pre || !std::strstr(pre, "libumockdev-preload")) {
        setenv("LD_PRELOAD", "libumockdev-preload.so.0", 1);
        const char* asan = std::getenv("ASAN_OPTIONS");
        setenv("ASAN_OPTIONS", (std::string(asan ? asan : "") + ":verify_asan_link_order=0").c_str(), 1);
        execv("/proc/self/exe", argv);
        std::perror("fringe-usb-sim: re-exec under umockdev's preload");
        return 2;
    }
    std::unique_ptr<dev::UsbEmulator> usb_emulator;
    try {
        const char* spec = std::getenv("FRINGE_USB_EMULATOR");
        usb_emulator = std::make_unique<dev::UsbEmulator>(dev::parse_usb_emulator_options(spec ? spec : ""));
    } catch (const std::exception& e) {
        std::fprintf(stderr, "error: %s\n", e.what());
        return 2;
    }
#endif
    auto logger = spdlog::stderr_color_mt("fringe");
    spdlog::set_default_logger(logger);
    spdlog::set_pattern("%^%l%$: %v");

    CLI::App app{"fringe: hardware-in-the-loop test bench for sin/cos encoder interpolation"};
    // The scenario schema's range (docs/schema.md): seeds are stored as JSON numbers.
    const CLI::Range kSeedRange(std::int64_t{0}, std::int64_t{1} << 53);
    app.set_version_flag("--version", std::string("fringe ") + FRINGE_VERSION);
    app.require_subcommand(1);

    GenOptions gen;
    auto* g = app.add_subcommand("gen", "Synthesise a scenario's encoder signals with truth into a capture file (.csv or .fcap)");
    g->add_option("scenario", gen.scenario, "Scenario JSON file")->required()->check(CLI::ExistingFile);
    g->add_option("-o,--output", gen.output, "Capture to write: .csv (with a .json sidecar) or .fcap (binary)")->required();
    g->add_option("--samples", gen.samples, "Override the number of samples (default: duration_s * sample_rate_hz)")->check(CLI::PositiveNumber);
    g->add_option("--seed", gen.seed, "Override the scenario's seed (0 to 2^53)")->check(kSeedRange);
    g->add_option("--block", gen.block, "Samples per block (output does not depend on it)")->check(CLI::Range(1, 1 << 24));
    g->add_flag("-q,--quiet", gen.quiet, "No summary or progress");

    EstimateOptions est_o;
    auto* es = app.add_subcommand("estimate", "Run an estimator on a capture; score it when the capture has theta_true");
    es->add_option("capture", est_o.capture, "Capture file (.csv with sidecar, .fcap, or a sigrok session .sr)")->check(CLI::ExistingFile);
    es->add_option("--channels", est_o.channels, "sigrok session (.sr) channels to read as columns: sin=CH1,cos=CH2[,theta_true=..,a=..,b=..,z=..] "
                                                  "(default: channels named like the columns)");
    es->add_option("--dut-interpolation", est_o.dut_interpolation, "Also score the DUT's ABZ lines (a, b, z columns) as \"dut\": its interpolation "
                                                                   "factor N (A/B periods per electrical cycle; docs/abz.md)")->check(CLI::Range(1, 1000000));
    es->add_option("--dut-index-count", est_o.dut_index_count, "With --dut-interpolation: the DUT's count at its Z index, mod 4N");
    es->add_option("--dut-offset-rad", est_o.dut_offset_rad, "With --dut-interpolation: electrical angle of count 0's lower edge");
    es->add_option("--estimator", est_o.estimator, "Estimator name (see --list)");
    es->add_option("--encoder", est_o.encoder, "Encoder profile JSON the estimator is told (default: the capture's metadata)")->check(CLI::ExistingFile);
    es->add_option("--param", est_o.params, "Estimator parameter key=value (repeatable)");
    es->add_option("-o,--output", est_o.output, "Estimates CSV to write: t,theta_rad,omega_rad_s,valid");
    es->add_option("--report", est_o.report, "Report JSON to write (scores and bounds when the capture has truth)");
    es->add_option("--settle-s", est_o.settle_s, "Seconds from the start excluded from scoring")->check(CLI::NonNegativeNumber);
    es->add_flag("--list", est_o.list, "List the estimators and their parameters");
    es->add_flag("--json", est_o.json_list, "With --list: as JSON");
    es->add_flag("-q,--quiet", est_o.quiet, "No summary or progress");

    RunCliOptions run_o;
    auto* rn = app.add_subcommand("run", "Run a scenario: generate, play through the device, estimate, score, apply limits; exit 0 PASS/MARGINAL, 1 FAIL, 2 ERROR");
    rn->add_option("scenario", run_o.scenario, "Scenario JSON file")->required()->check(CLI::ExistingFile);
    rn->add_option("--report", run_o.report, "Write the report JSON here");
    rn->add_option("--junit", run_o.junit, "Write JUnit XML here (one testcase per measurement)");
    rn->add_option("--html", run_o.html, "Write a self-contained HTML report here");
    rn->add_option("--data", run_o.data, "Data directory for the run history (default $FRINGE_DATA or ~/.local/share/fringe)");
    rn->add_option("--seed", run_o.seed, "Override the scenario's seed (0 to 2^53)")->check(kSeedRange);
    rn->add_flag("--no-db", run_o.no_db, "Do not record the run in the history");
    rn->add_option("--device", run_o.device, "Override the scenario's device URI (e.g. modbus+tcp://127.0.0.1:1502?board=dut-interpolator)");
    rn->add_option("--record", run_o.record, "Record the device input with aligned truth to this capture (.csv or .fcap)");
    rn->add_flag("-q,--quiet", run_o.quiet, "No summary or progress");
    rn->add_option("--server", run_o.server, "Run it on a fringe serve at this URL (http://HOST:PORT): the scenario is checked here, run there, its report fetched");
    rn->add_option("--token-file", run_o.token_file, "With --server: the service's bearer token file (default $FRINGE_DATA/token or ~/.local/share/fringe/token)");

    RunsOptions runs_o;
    auto* rs = app.add_subcommand("runs", "List the run history (newest first), or print one run's report");
    rs->add_option("--data", runs_o.data, "Data directory (default $FRINGE_DATA or ~/.local/share/fringe)");
    rs->add_option("--verdict", runs_o.verdict, "Only runs with this verdict (PASS, MARGINAL, FAIL, ERROR, ABORTED; any case)");
    rs->add_option("--scenario", runs_o.scenario, "Only runs of this scenario name");
    rs->add_option("--since", runs_o.since, "Only runs started at or after this UTC date or time (2026-11-21, 2026-11-21T15:00:00Z), today, yesterday or Nd");
    rs->add_option("--limit", runs_o.limit, "At most this many")->check(CLI::PositiveNumber);
    rs->add_option("--show", runs_o.show, "Print the summary of this run (its whole report with --json)");
    rs->add_flag("--json", runs_o.as_json, "As JSON");

    SweepOptions sw_o;
    auto* sw = app.add_subcommand("sweep", "Run a scenario over rows or a grid of parameter values, in parallel; write a table (CSV, Markdown)");
    sw->add_option("sweep", sw_o.sweep, "Sweep JSON file (e.g. fixtures/sweeps/table1.json)")->required()->check(CLI::ExistingFile);
    sw->add_option("-o,--csv", sw_o.csv, "Write the table as CSV here");
    sw->add_option("--md", sw_o.md, "Write the table as Markdown here");
    sw->add_option("--jobs", sw_o.jobs, "Parallel runs (default: the sweep's, else all cores)")->check(CLI::NonNegativeNumber);
    sw->add_flag("-q,--quiet", sw_o.quiet, "No table on stdout or progress");

    ServeOptions serve_o;
    auto* sv = app.add_subcommand("serve", "Serve the JSON/HTTP API and the browser UI; run scenarios from a queue");
    sv->add_option("--bind", serve_o.bind, "host:port to listen on; beyond loopback every request needs the token")->capture_default_str();
    sv->add_option("--data", serve_o.data, "Data directory: run history, uploads, token (default $FRINGE_DATA or ~/.local/share/fringe)");
    sv->add_option("--token-file", serve_o.token_file, "Bearer token file (default DATA/token; created with mode 0600 when absent)");
    sv->add_option("--fixtures", serve_o.fixtures, "Fixtures folder ({\"fixture\": NAME} and file references resolve here)")->capture_default_str();
    sv->add_option("--web", serve_o.web, "Browser UI folder")->capture_default_str();
    sv->add_option("--workers", serve_o.workers, "Runs executed in parallel (default: cores); runs on one board always queue");
    sv->add_option("--threads", serve_o.threads, "HTTP I/O threads")->check(CLI::Range(1, 64))->capture_default_str();
    sv->add_option("--max-upload-mb", serve_o.max_upload_mb, "Largest capture upload, MiB")->check(CLI::PositiveNumber)->capture_default_str();
    sv->add_option("--upload-quota-mb", serve_o.upload_quota_mb, "All uploaded captures together on disk, MiB (507 quota_exceeded beyond)")
        ->check(CLI::PositiveNumber)->capture_default_str();
    sv->add_option("--max-samples", serve_o.max_samples, "Samples per run (duration_s x sample_rate_hz; 413 too_many_samples beyond)")
        ->check(CLI::PositiveNumber)->capture_default_str();
    sv->add_option("--max-estimators", serve_o.max_estimators, "Estimators per run (413 too_many_estimators beyond)")->check(CLI::Range(1, 1000))->capture_default_str();
    sv->add_option("--max-limits", serve_o.max_limits, "Limits per run (413 too_many_limits beyond)")->check(CLI::Range(1, 10000))->capture_default_str();
    sv->add_option("--max-report-mb", serve_o.max_report_mb, "Largest report stored, MiB (a larger one ends the run as an error)")
        ->check(CLI::PositiveNumber)->capture_default_str();
    sv->add_option("--max-connections", serve_o.max_connections, "Connections served at once; more get 503 and are closed")
        ->check(CLI::Range(1, 100000))->capture_default_str();
    sv->add_option("--body-timeout", serve_o.body_timeout_s, "Seconds a JSON body may take to arrive; also the grace before the upload rate applies (408 beyond)")
        ->check(CLI::Range(1, 3600))->capture_default_str();
    sv->add_option("--upload-min-kibps", serve_o.upload_min_kib_s, "Slowest average upload rate accepted after --body-timeout seconds, KiB/s (408 below)")
        ->check(CLI::NonNegativeNumber)->capture_default_str();
    sv->add_flag("--allow-external", serve_o.allow_external, "Allow the external estimator (runs a command on this host) in HTTP requests");
    sv->add_option("--allow-device", serve_o.allow_device,
                   "Let clients' scenarios use devices matching this glob (repeatable): modbus+tcp://HOST:PORT, modbus+rtu:/dev/ttyUSB*, usb:1209:*; "
                   "loopback: and uploaded captures always, fixtures' devices are the operator's")
        ->allow_extra_args(false)
        ->check([](const std::string& p) -> std::string {
            const auto colon = p.find(':');
            const std::string scheme = colon == std::string::npos ? "" : p.substr(0, colon);
            for (const auto& d : dev::drivers())
                if (d.scheme == scheme && scheme != "loopback" && scheme != "capture") return "";
            return "'" + p + "' is not a device pattern: expected modbus+tcp://HOST:PORT, modbus+rtu:/dev/PATH or usb:VID:PID (globs * and ? allowed)";
        });
    sv->add_option("--allow-host", serve_o.allow_host,
                   "Answer requests whose Host header names this (repeatable), besides localhost, 127.0.0.1, [::1] and the bound address")
        ->allow_extra_args(false)
        ->check([](const std::string& h) -> std::string {
            const bool ok = !h.empty() && std::all_of(h.begin(), h.end(), [](char c) {
                return std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '_' || c == ':' || c == '[' || c == ']';
            });
            return ok ? "" : "'" + h + "' is not a host name";
        });

    BoardSimCli sim;
    auto* bs = app.add_subcommand("board-sim", "An emulated Modbus board (libmodbus server) for tests and demos");
    bs->add_option("--modbus", sim.o.listen, "tcp://127.0.0.1:PORT (0: a free port, printed) or rtu:/dev/ttyX")->required();
    bs->add_option("--board", sim.o.board, "Board profile name (fixtures/boards) or path")->capture_default_str();
    bs->add_option("--unit", sim.o.unit, "Modbus unit id (RTU)")->capture_default_str();
    bs->add_option("--baud", sim.o.baud, "RTU baud rate")->capture_default_str();
    bs->add_option("--estimator", sim.o.estimator, "On-board estimator of a DUT board (any registered)")->capture_default_str();
    bs->add_option("--param", sim.params, "On-board estimator parameter key=value (repeatable)");
    bs->add_option("--offset-sin-v", sim.o.offset_sin_v, "Analog path flaw: sin offset, V");
    bs->add_option("--offset-cos-v", sim.o.offset_cos_v, "Analog path flaw: cos offset, V");
    bs->add_option("--gain-mismatch", sim.o.gain_mismatch, "Analog path flaw: sin gain 1+g/2, cos gain 1-g/2");
    bs->add_option("--noise-v", sim.o.noise_v, "ADC input noise, V rms per conversion");
    bs->add_option("--adc-bits", sim.o.adc_bits, "ADC resolution (0: ideal)")->capture_default_str();
    bs->add_option("--adc-range-v", sim.o.adc_range_v, "ADC full scale, V")->capture_default_str();
    bs->add_option("--seed", sim.o.seed, "Noise seed")->capture_default_str();
    bs->add_option("--exception-every", sim.o.exception_every, "Fault: every Nth request answers with a Modbus exception");
    bs->add_option("--delay-ms", sim.o.delay_ms, "Fault: delay every reply");
    bs->add_option("--drop-after", sim.o.drop_after, "Fault: after N requests close every connection and stop");

    DevicesOptions dev_o;
    auto* dv = app.add_subcommand("devices", "List drivers with their settings, board profiles, and what is reachable");
    dv->add_option("--probe", dev_o.probe, "Also open this device URI and report it (repeatable)");
    dv->add_flag("--json", dev_o.as_json, "As JSON");

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        int rc = app.exit(e);
        return rc == 0 ? 0 : kExitError;
    }
    try {
        if (*g) return run_gen(gen);
        if (*es) return run_estimate(est_o);
        if (*rn) return run_run(run_o);
        if (*rs) return run_runs(runs_o);
        if (*sw) return run_sweep_cli(sw_o);
        if (*sv) return run_serve(serve_o);
        if (*bs) return run_board_sim_cli(sim);
        if (*dv) return run_devices(dev_o);
    } catch (const ConfigError& e) {
        spdlog::error("{}", e.what());
        return kExitError;
    } catch (const std::exception& e) {
        spdlog::error("{}", e.what());
        return kExitError;
    }
    return kExitError;
}
