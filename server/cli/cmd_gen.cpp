// fringe gen: synthesise a scenario's encoder signals with exact truth into a capture file.
#include "server/cli/commands.hpp"
#include "drivers/capture_file.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/base/text.hpp"
#include "signal_gen/analysis.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/generator.hpp"

#include <cmath>
#include <cstdio>

namespace fringe::cli {

namespace {

using nlohmann::json;

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
    // x.csv brings its sidecar x.json: never over the scenario it was made from
    refuse_overwrite({{"output", o.output}, {"output's sidecar", capture_format_for(o.output) == CaptureFormat::Csv ? sidecar_path(o.output) : ""}},
                     {{"scenario", o.scenario}});
    Scenario sc = load_scenario(o.scenario);
    if (o.seed >= 0) sc.seed = static_cast<std::uint64_t>(o.seed);
    if (sc.device.rfind("capture:", 0) == 0 && (sc.length_from_capture || sc.motion_unread || !sc.encoder_known))
        throw ConfigError("device", "a capture: scenario takes its rate, length, encoder and motion from the capture when it runs; fringe gen "
                                    "synthesises signals and needs them given (an encoder, motion, sample_rate_hz and duration_s)");
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

    Progress progress("gen", "samples", o.quiet);
    Block b;
    std::vector<double> keep_s, keep_th;  // first 2^20 samples for the summary
    constexpr std::size_t kKeep = 1 << 20;
    auto t_start = std::chrono::steady_clock::now();
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
        progress.update(k, total);
    }
    w.close();
    progress.clear();
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
    json summary = summarise(keep_s, keep_th);
    if (!o.quiet) {
        std::printf("wrote %s: %llu samples, %.6g s at %.6g Hz, seed %llu (%.2f s)\n", o.output.c_str(),
                    static_cast<unsigned long long>(total), static_cast<double>(total) / sc.sample_rate_hz,
                    sc.sample_rate_hz, static_cast<unsigned long long>(sc.seed), secs);
        std::printf("encoder %s (%s), %d lines, kappa %.4f, fundamental %.4f V\n", term_escape(sc.encoder.name).c_str(),
                    sc.encoder.model == ModelKind::Ideal ? "ideal" : "diffraction", sc.encoder.lines_per_rev,
                    sc.encoder.kappa_nominal(), sc.encoder.fundamental_amplitude_v());
        if (summary.contains("duty_cycle"))
            std::printf("sin channel over %.0f cycles: duty-cycle error %.2f %%, h2 %.2f %%, h3 %.3f %% of the fundamental %.4f V\n",
                        // +0.0: a rounding to -0.00 reads as a sign that is not there
                        summary["cycles"].get<double>(), std::fabs(summary["duty_cycle_error_pct"].get<double>()) < 0.005 ? 0.0 : summary["duty_cycle_error_pct"].get<double>(),
                        summary["h2_pct"].get<double>(), summary["h3_pct"].get<double>(),
                        summary["fundamental_v"].get<double>());
    }
    return kExitOk;
}

}  // namespace

Command add_gen(CLI::App& app) {
    auto o = std::make_shared<GenOptions>();
    auto* g = app.add_subcommand("gen", "Synthesise a scenario's encoder signals with truth into a capture file (.csv or .fcap)");
    g->add_option("scenario", o->scenario, "Scenario JSON file")->required()->check(CLI::ExistingFile);
    g->add_option("-o,--output", o->output, "Capture to write: .csv (with a .json sidecar) or .fcap (binary)")->required();
    g->add_option("--samples", o->samples, "Override the number of samples (default: duration_s * sample_rate_hz)")->check(CLI::PositiveNumber);
    g->add_option("--seed", o->seed, "Override the scenario's seed (0 to 2^53)")->check(kSeedRange);
    g->add_option("--block", o->block, "Samples per block (output does not depend on it)")->check(CLI::Range(1, 1 << 24));
    g->add_flag("-q,--quiet", o->quiet, "No summary or progress");
    return {g, [o] { return run_gen(*o); }};
}

}  // namespace fringe::cli
