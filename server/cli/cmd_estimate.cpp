// fringe estimate: run an estimator on a capture and score it against the capture's truth.
#include "server/cli/commands.hpp"
#include "estimator/estimator.hpp"
#include "drivers/capture_file.hpp"
#include "server/engine/capture_run.hpp"
#include "server/engine/scenario.hpp"
#include "server/report/report_formats.hpp"
#include "signal_gen/base/text.hpp"
#include "signal_gen/fastmath.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace fringe::cli {

namespace {

using nlohmann::json;

struct EstimateOptions {
    std::string capture, estimator, encoder, output, report, channels, interface, html, junit;
    std::vector<std::string> params;
    int dut_interpolation = 0;  // 0: no ABZ readout
    long long dut_index_count = 0;
    double dut_offset_rad = 0;
    double settle_s = 0.1;
    bool settle_given = false;
    double max_expanded_mb = static_cast<double>(kCaptureDefaultMaxExpandedBytes >> 20);
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
    // Each amplitude with the half-width of its 95 % interval (metrics "uncertainty").
    const json unc = m.value("uncertainty", json::object());
    std::printf("harmonics (rad, +- 95 %%):");
    for (const auto& h : m["harmonics"]) {
        std::printf(" %dx %.2e", h["order"].get<int>(), h["amplitude"]["rad"].get<double>());
        for (const auto& u : unc.value("harmonics", json::array()))
            if (u.value("order", 0) == h["order"].get<int>() && u["amplitude_rad"].is_array())
                std::printf("+-%.1e", (u["amplitude_rad"][1].get<double>() - u["amplitude_rad"][0].get<double>()) / 2);
    }
    std::printf("\n  1x..%dx hold %.1f %% of the error variance; broadband rest %.3e rad rms%s\n", static_cast<int>(m["harmonics"].size()),
                100.0 * ha["power_fraction"].get<double>(), ha["broadband_rms_rad"].get<double>(),
                interval_text(unc.value("broadband_rms_rad", json())).c_str());
    if (ha["note"].is_string()) std::printf("  (%s)\n", ha["note"].get<std::string>().c_str());
}

int run_estimate(const EstimateOptions& o) {
    if (o.list) {
        print_estimators(o.json_list);
        return kExitOk;
    }
    if (o.capture.empty()) throw ConfigError("capture", "a capture file is required (or --list)");
    if (o.estimator.empty()) throw ConfigError("estimator", "--estimator NAME is required (see --list)");
    // Without -o or --report the printed summary is the output; with -q as well there would be none.
    if (o.output.empty() && o.report.empty() && o.html.empty() && o.junit.empty() && o.quiet)
        throw ConfigError("output", "-q prints nothing: give -o ESTIMATES.csv and/or --report REPORT.json (or --html, --junit)");
    if (!std::isfinite(o.settle_s)) throw ConfigError("settle_s", "--settle-s must be a finite number of seconds");
    // A .csv's or .sr's sidecar is read from x.json whether or not it exists yet: a report
    // written there would be read as the capture's metadata next time.
    refuse_overwrite({{"output", o.output}, {"report", o.report}, {"html", o.html}, {"junit", o.junit}},
                     {{"capture", o.capture}, {"encoder profile", o.encoder}, {"interface profile", o.interface}});  // and the capture's sidecar
    CaptureRunOptions e;
    e.capture_path = o.capture;
    e.estimator = o.estimator;
    e.params = est::parse_param_assignments(est::find(o.estimator).params, o.params);
    if (!o.encoder.empty()) e.encoder = load_encoder(o.encoder);
    if (!o.interface.empty()) e.interface = load_interface(o.interface);
    e.estimates_path = o.output;
    if (!o.channels.empty()) e.capture.channels = parse_channel_map(o.channels);
    e.capture.max_expanded_bytes = static_cast<std::uint64_t>(std::min(o.max_expanded_mb * 1048576.0, 1.8e19));
    // Not given: the settle time the capture was recorded with (a Modbus sweep recorded with
    // settle_s 0 scored 28 of its 128 steps after a default 0.1 s), else 0.1 s.
    double settle_s = o.settle_s;
    if (!o.settle_given) {
        try {
            if (const auto recorded = recorded_settle_s(CaptureReader(o.capture, e.capture).meta())) settle_s = *recorded;
        } catch (const std::exception&) {  // unreadable: run_capture says why
        }
    }
    e.settle_s = settle_s;
    if (o.dut_interpolation > 0) e.abz = AbzConfig{o.dut_interpolation, o.dut_index_count, o.dut_offset_rad};
    Progress progress("estimate", "samples", o.quiet);
    if (progress.active()) e.progress = [&](std::uint64_t done) { progress.update(done); };
    json r;
    try {
        r = run_capture(e);
    } catch (const CaptureTooLarge& t) {
        throw CaptureError(std::string(t.what()) + " (--max-expanded-mb)");
    }
    progress.clear();
    if (!o.report.empty()) {
        std::FILE* f = std::fopen(o.report.c_str(), "w");
        if (!f) throw std::runtime_error(o.report + ": cannot write report");
        const std::string text = r.dump(2, ' ', false, json::error_handler_t::replace) + "\n";
        const bool ok = std::fwrite(text.data(), 1, text.size(), f) == text.size();
        if (std::fclose(f) != 0 || !ok) throw std::runtime_error(o.report + ": write failed");
    }
    if (!o.html.empty()) write_file_atomic(o.html, report_html(r));
    if (!o.junit.empty()) write_file_atomic(o.junit, junit_xml(r));
    // The run failed part way (the estimator's process died, the capture changed under it):
    // the report says so, the estimates stop there, and the exit code is 2.
    if (r["status"] != "done") throw std::runtime_error(r["error"].is_string() ? r["error"].get<std::string>() : "the run ended " + r["status"].dump());
    const json& cap = r["capture"];
    const json& lane = r["estimators"][0];  // the estimator; the DUT's readout, when asked for, is labelled "dut"
    const json& m = lane["metrics"];
    const double min_valid = r["scenario"]["scoring"]["min_valid_fraction"].get<double>();
    if (!o.quiet) {
        std::printf("%s on %s: %llu samples, %.3g M samples/s\n", o.estimator.c_str(), o.capture.c_str(),
                    static_cast<unsigned long long>(cap["samples"].get<std::uint64_t>()),
                    cap["timing"]["estimator_samples_per_s"].get<double>() / 1e6);
        bool notes_shown = false;
        if (!cap["has_truth"].get<bool>()) {
            const auto& es = cap["estimates"];
            const double vf = es["valid_fraction"].is_number() ? es["valid_fraction"].get<double>() : 0.0;
            std::printf("no theta_true in the capture: estimates only; valid %.1f %% of %llu samples\n",
                        100.0 * vf, static_cast<unsigned long long>(es["samples"].get<std::uint64_t>()));
            // The estimator's own account of why, on the same line (a pointer to notes that an
            // estimator without any left the reader looking at nothing).
            if (vf < min_valid) {
                const std::string why = state_notes(lane.value("state", json()));
                notes_shown = true;
                std::printf("warning: %s marked %.1f %% of the samples invalid: %s\n", o.estimator.c_str(), 100.0 * (1.0 - vf),
                            why.empty() ? "it gives no reason (its state says nothing); check its parameters (fringe estimate --list) before using the estimates"
                                        : (term_escape(why) + "; check this before using the estimates").c_str());
            }
            // The error without truth, against the signals' own phase (docs/self-reference.md).
            const json sr = lane.value("analysers", json::object()).value("self_reference", json());
            if (sr.is_object() && sr.value("measured", false) == true) {
                std::printf("self-referenced error (no truth: against the signals' own lag-free phase; its mean is not observable): rms %.3e rad +- %.1e "
                            "(%.4f %% of a period) over %llu windows, %.1f electrical cycles; harmonics",
                            sr["rms_rad"].get<double>(), sr["rms_u_rad"].get<double>(), 100.0 * sr["rms_rad"].get<double>() / kTwoPi,
                            static_cast<unsigned long long>(sr["windows"].get<std::uint64_t>()), sr["cycles"].get<double>());
                for (const auto& h : sr["harmonics"])
                    if (h["order"].get<int>() <= 4) std::printf(" %dx %.2e", h["order"].get<int>(), h["amplitude_rad"].get<double>());
                std::printf(" rad\n");
            } else if (sr.is_object()) {
                std::printf("self-referenced error: not measured: %s\n", term_escape(sr.value("why_not", std::string("no reason given"))).c_str());
            }
            for (const auto& w : r["warnings"]) std::printf("warning: %s\n", term_escape(w.value("message", std::string())).c_str());
        } else if (m["scored"].get<std::uint64_t>() == 0) {
            const double n = static_cast<double>(cap["samples"].get<std::uint64_t>());
            std::printf("no scored samples: %.0f samples (%.6g s), %llu after the %.6g s settle time, %llu of them marked invalid by the estimator\n", n,
                        n / cap["sample_rate_hz"].get<double>(), static_cast<unsigned long long>(m["evidence"]["samples_after_settle"].get<std::uint64_t>()),
                        settle_s, static_cast<unsigned long long>(m["invalid_after_settle"].get<std::uint64_t>()));
        } else {
            const auto& ev = m["evidence"];
            const json unc = m.value("uncertainty", json::object());
            std::printf("error after %.3g s settle (%llu samples, %.1f electrical cycles, valid %.1f %%): rms %.3e rad%s (%.4f %% of a period), std %.3e, mean %.3e, max|e| %.3e rad, slipped %llu\n",
                        settle_s, static_cast<unsigned long long>(m["scored"].get<std::uint64_t>()), ev["scored_cycles"].get<double>(),
                        100.0 * ev["valid_fraction"].get<double>(), m["rms"]["rad"].get<double>(), interval_text(unc.value("rms_rad", json())).c_str(),
                        m["rms"]["percent_period"].get<double>(), m["std"]["rad"].get<double>(), m["mean"]["rad"].get<double>(),
                        m["max_abs"]["rad"].get<double>(), static_cast<unsigned long long>(m["slipped_samples"].get<std::uint64_t>()));
            print_harmonics(m);
            // fringe estimate has no limits; say when a run would not have had enough evidence.
            const auto& rules = r["scenario"]["scoring"];
            if (m["scored"].get<std::uint64_t>() < rules["min_scored_samples"].get<std::uint64_t>() ||
                ev["scored_cycles"].get<double>() < rules["min_scored_cycles"].get<double>())
                std::printf("warning: only %llu scored samples over %.2f electrical cycles: below a run's evidence minimum (%llu samples, %.3g cycles); "
                            "treat these figures as indicative\n",
                            static_cast<unsigned long long>(m["scored"].get<std::uint64_t>()), ev["scored_cycles"].get<double>(),
                            static_cast<unsigned long long>(rules["min_scored_samples"].get<std::uint64_t>()), rules["min_scored_cycles"].get<double>());
            const auto& b = lane["bounds"];
            if (b.is_object() && b.contains("per_sample_crb_rad")) {
                std::printf("bounds: per-sample CRB %.3e rad", b["per_sample_crb_rad"].get<double>());
                if (b.contains("pcrb_rad")) std::printf(", PCRB %.3e rad (noise-only %.3e)", b["pcrb_rad"].get<double>(), b["pcrb_noise_only_rad"].get<double>());
                if (!b["efficiency"].is_null()) std::printf(", efficiency %.3g vs %s", b["efficiency"].get<double>(), b["efficiency_against"].get<std::string>().c_str());
                std::printf("\n");
            }
            // The run's warnings (the preflight's, convention findings, efficiency), and the
            // evidence check on the valid share the figures rest on.
            for (const auto& w : r["warnings"]) std::printf("warning: %s\n", term_escape(w.value("message", std::string())).c_str());
            const double vf = ev["valid_fraction"].get<double>();
            if (vf < min_valid)
                std::printf("warning: only %.3g %% of the %llu samples after the settle time are valid (a run needs %.3g %%): the figures describe those %llu "
                            "samples only, not the capture\n",
                            100.0 * vf, static_cast<unsigned long long>(ev["samples_after_settle"].get<std::uint64_t>()), 100.0 * min_valid,
                            static_cast<unsigned long long>(m["scored"].get<std::uint64_t>()));
        }
        if (const std::string n = state_notes(lane.value("state", json())); !n.empty() && !notes_shown) std::printf("%s: %s\n", o.estimator.c_str(), term_escape(n).c_str());
        print_signal_summary(r);
        if (r["verdict"].is_string() && !cap.value("has_truth", true))
            std::printf("verdict %s: the signals graded against %s (the estimator's error is self-referenced and has no limit)\n",
                        r["verdict"].get<std::string>().c_str(), term_escape(r["scenario"]["interface"].value("name", std::string("the interface profile"))).c_str());
        for (const auto& d : r["estimators"]) {
            if (d.value("label", "") != "dut" || d.value("name", "") != "dut") continue;
            const auto& ro = d["metrics"]["abz"];
            const auto& dm = d["metrics"];
            std::printf("dut (ABZ, %d counts per cycle, reference %s): %llu edges, %llu illegal transitions, %llu index pulses (%llu off)",
                        ro["counts_per_cycle"].get<int>(), ro["reference"].get<std::string>().c_str(),
                        static_cast<unsigned long long>(ro["edges"].get<std::uint64_t>()),
                        static_cast<unsigned long long>(ro["illegal_transitions"].get<std::uint64_t>()),
                        static_cast<unsigned long long>(ro["index_pulses"].get<std::uint64_t>()),
                        static_cast<unsigned long long>(ro["index_errors"].get<std::uint64_t>()));
            if (dm["rms"].is_object())
                std::printf(", error rms %.3e rad, max|e| %.3e rad", dm["rms"]["rad"].get<double>(), dm["max_abs"]["rad"].get<double>());
            std::printf("\n");
        }
    }
    // Truth but nothing scored: no figures, and a script gating on the exit code must not read
    // that as success (a run's evidence measurements FAIL the same way).
    if (cap["has_truth"].get<bool>() && m["scored"].get<std::uint64_t>() == 0) return kExitFail;
    return kExitOk;
}

}  // namespace

Command add_estimate(CLI::App& app) {
    auto o = std::make_shared<EstimateOptions>();
    auto* es = app.add_subcommand("estimate", "Run an estimator on a capture; score it when the capture has theta_true");
    es->add_option("capture", o->capture, "Capture file (.csv with sidecar, .fcap, or a sigrok session .sr)")->check(CLI::ExistingFile);
    es->add_option("--channels", o->channels, "sigrok session (.sr) channels to read as columns: sin=CH1,cos=CH2[,theta_true=..,a=..,b=..,z=..] "
                                              "(default: channels named like the columns)");
    es->add_option("--dut-interpolation", o->dut_interpolation, "Also score the DUT's ABZ lines (a, b, z columns) as \"dut\": its interpolation "
                                                               "factor N (A/B periods per electrical cycle; docs/abz.md)")->check(CLI::Range(1, 1000000));
    es->add_option("--dut-index-count", o->dut_index_count, "With --dut-interpolation: the DUT's count at its Z index, mod 4N");
    es->add_option("--dut-offset-rad", o->dut_offset_rad, "With --dut-interpolation: electrical angle of count 0's lower edge");
    es->add_option("--estimator", o->estimator, "Estimator name (see --list)");
    es->add_option("--encoder", o->encoder, "Encoder profile JSON the estimator is told (default: the capture's metadata)")->check(CLI::ExistingFile);
    es->add_option("--interface", o->interface,
                   "Interface profile JSON to grade the signals against (e.g. fixtures/interfaces/1vpp.json; docs/signal-quality.md): its bands are the report's "
                   "measurements and verdict, with or without truth")
        ->check(CLI::ExistingFile);
    es->add_option("--param", o->params, "Estimator parameter key=value (repeatable)");
    es->add_option("-o,--output", o->output, "Estimates CSV to write: t,theta_rad,omega_rad_s,valid (without -o and --report: the summary only)");
    es->add_option("--report", o->report, "Report JSON to write (scores and bounds when the capture has truth)");
    es->add_option("--html", o->html, "Self-contained HTML report to write (the signals' gauges, Lissajous and trends; the error plots)");
    es->add_option("--junit", o->junit, "JUnit XML to write (one testcase per measurement, every metric as a property)");
    es->add_option("--max-expanded-mb", o->max_expanded_mb, "Most sample data a sigrok session (.sr) may expand to, MiB "
                                                            "(its members as declared; a limit against ZIP bombs)")
        ->check(kFinitePositive)->capture_default_str();
    auto* st = es->add_option("--settle-s", o->settle_s, "Seconds from the start excluded from scoring (default: the settle_s the capture was recorded with, else 0.1)")
                   ->check(kFiniteNonNegative);
    es->add_flag("--list", o->list, "List the estimators and their parameters");
    es->add_flag("--json", o->json_list, "With --list: as JSON");
    es->add_flag("-q,--quiet", o->quiet, "No summary or progress");
    return {es, [o, st] {
                o->settle_given = st->count() > 0;
                return run_estimate(*o);
            }};
}

}  // namespace fringe::cli
