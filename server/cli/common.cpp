// What the fringe commands share (common.hpp).
#include "common.hpp"
#include "drivers/capture_file.hpp"
#include "server/analysis/metrics.hpp"
#include "server/report/report_formats.hpp"
#include "signal_gen/base/text.hpp"

#include "signal_gen/base/config.hpp"

#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <unistd.h>

namespace fringe::cli {

using nlohmann::json;

Progress::Progress(std::string label, std::string unit, bool quiet)
    : label_(std::move(label)), unit_(std::move(unit)), active_(!quiet && isatty(STDERR_FILENO)) {}

void Progress::update(std::uint64_t done, std::uint64_t total) {
    if (!active_) return;
    const auto now = std::chrono::steady_clock::now();
    if (shown_ && now - last_ < std::chrono::milliseconds(250) && done != total) return;
    last_ = now;
    shown_ = true;
    if (total)
        std::fprintf(stderr, "\r%s: %5.1f %% (%llu / %llu %s)", label_.c_str(), 100.0 * static_cast<double>(done) / static_cast<double>(total),
                     static_cast<unsigned long long>(done), static_cast<unsigned long long>(total), unit_.c_str());
    else
        std::fprintf(stderr, "\r%s: %llu %s", label_.c_str(), static_cast<unsigned long long>(done), unit_.c_str());
    std::fflush(stderr);
}

void Progress::clear() {
    if (!shown_) return;
    std::fprintf(stderr, "\r%70s\r", "");
    std::fflush(stderr);
    shown_ = false;
}

namespace {
std::atomic<bool> g_cancel{false};
extern "C" void on_cancel_signal(int) { g_cancel.store(true); }
}  // namespace

std::atomic<bool>& cancel_flag() { return g_cancel; }

void install_cancel_handlers() {
    std::signal(SIGINT, on_cancel_signal);
    std::signal(SIGTERM, on_cancel_signal);
}

namespace {
bool same_file(const std::string& a, const std::string& b) {
    namespace fs = std::filesystem;
    std::error_code ec1, ec2;
    if (fs::exists(a, ec1) && fs::exists(b, ec2)) {
        std::error_code ec;
        const bool eq = fs::equivalent(a, b, ec);
        if (!ec) return eq;
    }
    std::error_code ec;
    const fs::path pa = fs::weakly_canonical(fs::absolute(a), ec);
    const fs::path pb = fs::weakly_canonical(fs::absolute(b), ec);
    return pa.lexically_normal() == pb.lexically_normal();
}
}  // namespace

CLI::Validator finite_number(bool allow_zero) {
    return CLI::Validator(
        [allow_zero](std::string& text) -> std::string {
            double x = 0;
            if (!CLI::detail::lexical_cast(text, x)) return "'" + text + "' is not a number";
            if (!std::isfinite(x)) return "'" + text + "' is not a finite number";
            if (allow_zero ? x < 0 : x <= 0) return "'" + text + "' must be " + (allow_zero ? "0 or more" : "more than 0");
            return {};
        },
        allow_zero ? "NUMBER >= 0" : "NUMBER > 0");
}

void refuse_overwrite(const std::vector<NamedPath>& outputs, std::vector<NamedPath> inputs) {
    // A CSV or sigrok capture is two files: its sidecar is an input too (calibrate -o x.json on
    // x.csv replaced the sidecar and left the capture unreadable).
    const std::size_t n_in = inputs.size();
    for (std::size_t k = 0; k < n_in; ++k)
        if (inputs[k].role == "capture" && !inputs[k].path.empty()) {
            bool sidecar = false;
            try {
                sidecar = capture_format_for(inputs[k].path) != CaptureFormat::Binary;
            } catch (const std::exception&) {  // not a capture's name: the reader says so later
            }
            if (sidecar) inputs.push_back({"capture's sidecar", sidecar_path(inputs[k].path)});
        }
    for (std::size_t i = 0; i < outputs.size(); ++i) {
        const auto& o = outputs[i];
        if (o.path.empty()) continue;
        for (const auto& in : inputs)
            if (!in.path.empty() && same_file(o.path, in.path))
                throw ConfigError(o.role, o.path + " is the " + in.role + (in.path == o.path ? "" : " (" + in.path + ")") +
                                              ": writing it would destroy it; name another file");
        for (std::size_t j = 0; j < i; ++j)
            if (!outputs[j].path.empty() && same_file(o.path, outputs[j].path))
                throw ConfigError(o.role, o.path + " is also the " + outputs[j].role + ": name two different files");
    }
}

std::string state_notes(const json& state) {
    std::string out;
    if (!state.is_object()) return out;
    const auto lock = state.value("loss_of_lock", json::object());
    const long long events = lock.value("events", 0LL);
    if (events > 0)
        out += "loss of lock " + std::to_string(events) + (events == 1 ? " time" : " times") + " (" +
               std::to_string(lock.value("samples_invalid", 0LL)) + " samples invalid while it re-acquired)";
    const auto count = [&](const char* key) { return state.contains(key) && state[key].is_number_integer() ? state[key].get<long long>() : 0LL; };
    const auto add = [&](const std::string& t) { out += (out.empty() ? "" : "; ") + t; };
    if (const long long n = count("signal_changes"); n > 0)
        add("the signal changed " + std::to_string(n) + (n == 1 ? " time" : " times") + " (shape learnt afresh; errors are large until it has been)");
    if (const long long n = count("outlier_samples"); n > 0)
        add(std::to_string(n) + " outlier sample" + (n == 1 ? "" : "s") + " not taken in");
    if (const long long n = count("skipped_updates"); n > 0)
        add(std::to_string(n) + " sample" + (n == 1 ? "" : "s") + " not taken in (outliers or singular updates)");
    if (const long long n = count("nonfinite_samples"); n > 0)
        add(std::to_string(n) + " non-finite sample" + (n == 1 ? "" : "s") + " skipped");
    // A fitting estimator (atan2-ellipse): how its fit went; before its first fit its output is invalid.
    if (state.contains("fit_status") && state["fit_status"].is_string()) {
        const long long fits = count("fits");
        add("ellipse fit " + state["fit_status"].get<std::string>() + " (" + std::to_string(fits) + (fits == 1 ? " fit" : " fits") +
            (state.contains("accepted_points") && state["accepted_points"].is_number_integer() ? ", " + std::to_string(state["accepted_points"].get<long long>()) + " points seen" : "") +
            "; the output is marked invalid until the first fit)");
    }
    if (state.contains("message") && state["message"].is_string())
        out += (out.empty() ? "" : "; ") + state["message"].get<std::string>();
    return out;
}

std::string interval_text(const json& iv) {
    if (!iv.is_array() || iv.size() != 2 || !iv[0].is_number() || !iv[1].is_number()) return "";
    char b[80];
    std::snprintf(b, sizeof b, " (95 %% %.3e..%.3e)", iv[0].get<double>(), iv[1].get<double>());
    return b;
}

namespace {
// One summary column of a lane (or of the run): "column value unit (95 % lo..hi)", "" when not measured.
std::string summary_cell(const MetricInfo& mi, const json& src) {
    const auto v = mi.value(src, nullptr);
    if (!v) return "";
    char b[40];
    if (*v == std::floor(*v) && std::fabs(*v) < 1e15) std::snprintf(b, sizeof b, "%.0f", *v);
    else if (std::fabs(*v) >= 1e-2 && std::fabs(*v) < 1e5) std::snprintf(b, sizeof b, "%.4g", *v);
    else std::snprintf(b, sizeof b, "%.3e", *v);
    std::string c = mi.column + " " + b + (mi.unit.empty() ? "" : " " + mi.unit);
    if (mi.interval)
        if (const auto iv = mi.interval(src, *v)) c += interval_text(json::array({iv->first, iv->second}));
    return c;
}
}  // namespace

// The signals' quality, once for the run (docs/signal-quality.md): its summary columns, or why
// it was not analysed.
void print_signal_summary(const json& r) {
    std::string line;
    for (const auto* mi : summary_metrics(true)) {
        if (const std::string c = summary_cell(*mi, r); !c.empty()) line += (line.empty() ? "" : ", ") + c;
    }
    const json sq = r.value("signal", json());
    if (!line.empty())
        std::printf("  %-20s %s (%s periods)\n", "signal", line.c_str(), sq.value("periods", json()).dump().c_str());
    else if (sq.is_object() && sq.value("note", json()).is_string())
        std::printf("  %-20s not analysed: %s\n", "signal", term_escape(sq["note"].get<std::string>()).c_str());
    print_signal_bands(r);
}

namespace {
std::string band_number(const json& v, const char* open, int digits = 4) {
    if (!v.is_number()) return open;
    char b[40];
    std::snprintf(b, sizeof b, "%.*g", digits, v.get<double>());
    return b;
}

// A text gauge of a value against its bands, 25 characters between [ and ]: '=' the mounting
// tolerance, '~' the rest of the specification, '.' outside it; '|' the value ('<' or '>' at an
// end when it is off the scale). The scale spans the specification and a third of it either side.
std::string band_gauge(const json& value, const json& band) {
    const json spec = band.value("spec", json()), mount = band.value("mounting", json());
    if (!spec.is_array() || spec.size() != 2 || !spec[0].is_number() || !spec[1].is_number()) return "";
    const double lo = spec[0].get<double>(), hi = spec[1].get<double>(), w = hi - lo;
    constexpr int kCells = 25;
    const double x0 = lo - w / 3, x1 = hi + w / 3, dx = (x1 - x0) / kCells;
    if (!(w > 0) || !std::isfinite(dx) || !(dx > 0)) return "";  // a band too wide to draw (its width overflows)
    std::string g(kCells, '.');
    for (int i = 0; i < kCells; ++i) {
        const double x = x0 + (i + 0.5) * dx;
        if (x >= lo && x <= hi) g[i] = '~';
        if (mount.is_array() && mount.size() == 2 && (!mount[0].is_number() || x >= mount[0].get<double>()) &&
            (!mount[1].is_number() || x <= mount[1].get<double>()) && x >= lo && x <= hi)
            g[i] = '=';
    }
    if (value.is_number()) {
        const double v = value.get<double>();
        if (v < x0) g[0] = '<';
        else if (v >= x1) g[kCells - 1] = '>';
        else if (const double cell = (v - x0) / dx; std::isfinite(cell)) g[std::clamp(static_cast<int>(cell), 0, kCells - 1)] = '|';
    }
    return "[" + g + "]";
}
}  // namespace

// The signals graded against the scenario's interface profile: one line a band, with a gauge.
void print_signal_bands(const json& r) {
    const json ms = r.value("measurements", json::array());
    bool header = false;
    for (const auto& m : ms) {
        if (m.value("estimator", "") != "run" || !m.value("interface", json()).is_string()) continue;
        if (!header) {
            std::printf("  %-20s graded against %s: '=' mounting tolerance, '~' specification, '|' the value\n", "signal bands",
                        term_escape(m["interface"].get<std::string>()).c_str());
            header = true;
        }
        const std::string metric = m.value("metric", "");
        const auto mi = find_metric(metric);
        const std::string label = mi && !mi->column.empty() ? mi->column : metric;
        const json band = m.value("band", json::object());
        const json spec = band.value("spec", json()), mount = band.value("mounting", json());
        std::string bands;
        if (spec.is_array() && spec.size() == 2) bands = "spec " + band_number(spec[0], "-inf") + ".." + band_number(spec[1], "inf");
        if (mount.is_array() && mount.size() == 2) bands += ", mounting " + band_number(mount[0], "-inf") + ".." + band_number(mount[1], "inf");
        const std::string unit = m.value("unit", "");
        // Six digits: a value just outside an edge must not print as the edge.
        const std::string val = m["value"].is_number() ? band_number(m["value"], "", 6) + (unit.empty() ? "" : " " + unit) : "not measured";
        std::printf("    %-18s %-14s %s  %s: %s\n", term_escape(label).c_str(), val.c_str(), band_gauge(m["value"], band).c_str(), bands.c_str(),
                    term_escape(m.value("grade", std::string("-"))).c_str());
    }
}

// Every string here comes from a report: a scenario file, a client or a device wrote it.
namespace {

// A scenario's "calibrate": the before and after passes side by side, per lane.
void print_calibration_summary(const json& r) {
    const json c = r.value("calibration", json());
    if (!c.is_object()) return;
    const auto str = [](const json& v) { return term_escape(v.is_string() ? v.get<std::string>() : v.dump()); };
    const auto num = [](const json& v, const char* f = "%.4g") {
        if (!v.is_number()) return std::string("-");
        char b[32];
        std::snprintf(b, sizeof b, f, v.get<double>());
        return std::string(b);
    };
    const json& on = c.value("computed_on", json::object());
    const json& ver = c.value("verified_on", json());
    std::printf("calibration of %s: %s\n", str(c["lane"]).c_str(), str(c["status"]).c_str());
    if (c.value("why", json()).is_string()) std::printf("  %s\n", str(c["why"]).c_str());
    const auto seed = [&](const json& p) { return p.value("seed", json()).is_number() ? str(p["seed"]) : std::string("not recorded"); };
    std::printf("  computed on the before pass (seed %s, %s%s)\n", seed(on).c_str(),
                on.contains("capture") && on["capture"].is_string() ? ("capture " + str(on["capture"])).c_str() : str(on.value("device", json())).c_str(),
                on.value("error_source", json()).is_string() ? (on["error_source"] == "truth" ? ", truth-scored error" : ", self-referenced error") : "");
    if (ver.is_object())
        std::printf("  verified on the after pass (seed %s, %s)\n", seed(ver).c_str(),
                    ver.contains("capture") && ver["capture"].is_string() ? ("capture " + str(ver["capture"])).c_str() : str(ver.value("device", json())).c_str());
    if (c.value("correction", json()).is_object()) {
        const json& f = c["correction"]["file"];
        std::printf("  correction: %s (%zu entries%s), predicted %s rad rms\n", str(c["correction"]["path"]).c_str(),
                    f.value("table_rad", json::array()).size(), f.contains("lissajous") ? ", Lissajous stage" : "",
                    num(c.value("predicted_rms_rad", json())).c_str());
    }
    std::printf("  %-20s %-14s %11s %11s %11s %11s %11s %9s  %s\n", "lane", "error", "rms before", "rms after", "max before", "max after",
                "CRB", "after/CRB", "correction");
    for (const auto& l : c.value("lanes", json::array())) {
        const json b = l.value("before", json::object()), a = l.value("after", json());
        // The error each pass was measured by: one word when both agree, else before/after.
        const auto src_word = [](const json& p) {
            const json v = p.is_object() ? p.value("error_source", json()) : json();
            return !v.is_string() ? std::string("-") : v == "truth" ? std::string("truth") : std::string("self-ref");
        };
        const std::string sb = src_word(b), sa = src_word(a);
        const std::string src = !a.is_object() || sa == sb ? sb : sb + "/" + sa;
        const json cor = l.value("correction", json());
        std::string applied = !cor.is_object() ? "-" : cor.value("applied", false) ? (str(cor["kind"]) == "external_env" ? std::string("handed to the child (external_env)") : "applied (" + str(cor["kind"]) + ")") : "not applied: " + str(cor.value("why_not", json()));
        const json crb = a.is_object() && a.value("per_sample_crb_rad", json()).is_number() ? a["per_sample_crb_rad"] : b.value("per_sample_crb_rad", json());
        std::printf("  %-20s %-14s %11s %11s %11s %11s %11s %9s  %s\n", str(l["label"]).c_str(), src.c_str(), num(b.value("rms_rad", json())).c_str(),
                    a.is_object() ? num(a.value("rms_rad", json())).c_str() : "-", num(b.value("max_abs_rad", json())).c_str(),
                    a.is_object() ? num(a.value("max_abs_rad", json())).c_str() : "-", num(crb).c_str(),
                    a.is_object() ? num(a.value("rms_over_crb", json()), "%.3g").c_str() : "-", applied.c_str());
    }
    std::printf("  limits: %s\n", str(c.value("limits", json("-"))).c_str());
}

}  // namespace

void print_run_summary(const json& r, const std::string& name, bool all_metrics) {
    const auto str = [](const json& v) { return term_escape(v.is_string() ? v.get<std::string>() : v.dump()); };
    std::printf("run %s: %s %s (%s)\n", str(r["id"]).c_str(), term_escape(name).c_str(), str(r["verdict"]).c_str(), str(r["status"]).c_str());
    if (r["error"].is_string()) std::printf("error: %s\n", str(r["error"]).c_str());
    for (const auto& w : r.value("warnings", json::array())) std::printf("warning: %s\n", term_escape(w.value("message", "")).c_str());
    for (const auto& e : r["estimators"]) {
        const auto& m = e["metrics"];
        const auto& ev = m.value("evidence", json::object());
        const json sr = e.value("analysers", json::object()).value("self_reference", json());
        if (!m["rms"].is_object() && sr.is_object() && sr.value("measured", false) == true) {
            // Without truth: the self-referenced error, with its uncertainty, is what was measured.
            const double rms = sr["rms_rad"].get<double>(), u = sr["rms_u_rad"].get<double>();
            std::printf("  %-20s self-referenced (no truth) rms %.4g rad (95 %% %.4g..%.4g), %llu windows, %.1f electrical cycles, valid %.4g\n",
                        str(e["label"]).c_str(), rms, rms - 1.96 * u, rms + 1.96 * u, static_cast<unsigned long long>(sr.value("windows", std::uint64_t{0})),
                        sr.value("cycles", 0.0), sr.value("valid_fraction", json()).is_number() ? sr["valid_fraction"].get<double>() : 0.0);
            continue;
        }
        if (!m["rms"].is_object() && sr.is_object() && sr.value("why_not", json()).is_string()) {
            std::printf("  %-20s no truth, and the self-referenced error was not measured: %s\n", str(e["label"]).c_str(), str(sr["why_not"]).c_str());
            continue;
        }
        if (!m["rms"].is_object()) {
            std::printf("  %-20s no scored samples (%llu after the settle time, valid %s)\n", str(e["label"]).c_str(),
                        static_cast<unsigned long long>(ev.value("samples_after_settle", std::uint64_t{0})),
                        ev.value("valid_fraction", json()).is_number() ? (std::to_string(100.0 * ev["valid_fraction"].get<double>()).substr(0, 5) + " %").c_str() : "-");
            continue;
        }
        // The metric table's summary columns that were measured, each with its unit and interval:
        // a line for the error figures, one for the bounds, one for the evidence.
        for (const char* group : {"error", "bound", "evidence"}) {
            std::string line;
            for (const auto* mi : summary_metrics()) {
                if (mi->group != group) continue;
                if (const std::string c = summary_cell(*mi, e); !c.empty()) line += (line.empty() ? "" : ", ") + c;
            }
            if (!line.empty()) std::printf("  %-20s %s\n", std::string(group) == "error" ? str(e["label"]).c_str() : "", line.c_str());
        }
    }
    print_calibration_summary(r);
    print_signal_summary(r);
    if (all_metrics) std::printf("%s", term_escape(metrics_text(r), true).c_str());
    for (const auto& e : r["estimators"])
        if (const std::string n = state_notes(e.value("state", json())); !n.empty())
            std::printf("  %-20s %s\n", str(e["label"]).c_str(), term_escape(n).c_str());
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
        if (m.value("interface", json()).is_string() && m.value("grade", json()).is_string()) {  // an interface profile's band
            lim += "; " + str(m["interface"]) + ": " + str(m["grade"]);
            const json mount = m["band"].value("mounting", json());
            if (mount.is_array() && mount.size() == 2)
                lim += " (mounting " + (mount[0].is_number() ? fmt(mount[0]) : std::string("-inf")) + ".." +
                       (mount[1].is_number() ? fmt(mount[1]) : std::string("inf")) + ")";
        }
        char val[32];
        std::snprintf(val, sizeof val, "%s", fmt(m["value"]).c_str());
        const std::string unit = m["value"].is_number() && !m["unit"].get<std::string>().empty() ? " " + m["unit"].get<std::string>() : "";
        std::printf("  %-8s %s %s = %s%s%s (limit %s%s)%s\n", str(m["outcome"]).c_str(), str(m["estimator"]).c_str(),
                    str(m["metric"]).c_str(), val, unit.c_str(), interval_text(m.value("interval_95", json())).c_str(), lim.c_str(),
                    m.value("implicit", false) ? ", evidence" : "", m.contains("reason") ? ("; " + str(m["reason"])).c_str() : "");
    }
}

}  // namespace fringe::cli
