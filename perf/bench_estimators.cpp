// Estimator throughput, samples/s on one core, on the paper's 1.6 % duty-cycle signal
// (16-bit ADC, noise) pre-generated outside the timed loop. Each iteration pushes one
// 65536-sample block through an estimator that keeps running (no reset), as in a long run.
#include "estimator/estimator.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/generator.hpp"

#include <benchmark/benchmark.h>

using namespace fringe;

namespace {

struct Signal {
    Block b;
    EncoderProfile enc;
    double fs;
};

Signal make_signal(const std::string& scenario) {
    const auto sc = load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/" + scenario);
    Signal out{{}, sc.encoder, sc.sample_rate_hz};
    Generator g(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed);
    out.b.resize(65536, false);
    g.generate(0, out.b);
    return out;
}

const Signal& paper_signal() {
    static const Signal s = make_signal("paper-duty1p6.json");
    return s;
}

// The signal of fixtures/scenarios/perf-1e7.json (paper-d2-analog at 106.7 Hz electrical):
// perf/harness_ratio.sh sets a run of that scenario beside the estimator alone.
const Signal& perf_signal() {
    static const Signal s = make_signal("perf-1e7.json");
    return s;
}

void run_on(benchmark::State& state, const Signal& s, const std::string& name, const nlohmann::json& params) {
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = s.fs;
    cfg.encoder = s.enc;
    cfg.params = params;
    auto e = est::make(name, cfg);
    const std::size_t n = s.b.size();
    std::vector<double> th(n), om(n);
    std::vector<std::uint8_t> v(n);
    e->process({s.b.sin_v, s.b.cos_v}, {th, om, v});  // past acquisition
    for (auto _ : state) {
        e->process({s.b.sin_v, s.b.cos_v}, {th, om, v});
        benchmark::DoNotOptimize(th.data());
        benchmark::ClobberMemory();
    }
    state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * n));
}

void run(benchmark::State& state, const std::string& name, const nlohmann::json& params) { run_on(state, paper_signal(), name, params); }
void run_perf(benchmark::State& state, const std::string& name, const nlohmann::json& params) { run_on(state, perf_signal(), name, params); }

}  // namespace

#define FRINGE_BENCH(label, name, params) \
    BENCHMARK_CAPTURE(run, label, std::string(name), nlohmann::json(params))->Unit(benchmark::kMillisecond)

FRINGE_BENCH(atan2, "atan2", nlohmann::json::object());
// On perf-1e7.json's own signal, for perf/harness_ratio.sh.
BENCHMARK_CAPTURE(run_perf, ekf_diffraction_cv_perf1e7, std::string("ekf-diffraction"), nlohmann::json::object())->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(run_perf, atan2_perf1e7, std::string("atan2"), nlohmann::json::object())->Unit(benchmark::kMillisecond);
FRINGE_BENCH(atan2_ellipse_recursive, "atan2-ellipse", (nlohmann::json{{"mode", "recursive"}}));
FRINGE_BENCH(pll2, "pll2", nlohmann::json::object());
FRINGE_BENCH(ekf_ideal_cv, "ekf-ideal", nlohmann::json::object());
FRINGE_BENCH(ekf_diffraction_cv, "ekf-diffraction", nlohmann::json::object());
FRINGE_BENCH(ekf_diffraction_ca, "ekf-diffraction", (nlohmann::json{{"kinematics", "ca"}}));
FRINGE_BENCH(ekf_diffraction_agc_kappa_bias, "ekf-diffraction",
             (nlohmann::json{{"agc", true}, {"track_kappa", true}, {"track_offsets", true}}));
FRINGE_BENCH(ekf_sin_only, "ekf-sin-only", nlohmann::json::object());
FRINGE_BENCH(ekf_parallel, "ekf-parallel", nlohmann::json::object());
FRINGE_BENCH(ekf_rectified, "ekf-rectified", nlohmann::json::object());
FRINGE_BENCH(ekf_selfcal, "ekf-selfcal", nlohmann::json::object());
FRINGE_BENCH(closed_loop, "closed-loop", nlohmann::json::object());
FRINGE_BENCH(ekf_auto, "ekf-auto", nlohmann::json::object());

BENCHMARK_MAIN();
