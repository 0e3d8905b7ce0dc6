// What fringe's own analysis costs per sample, each analyser alone on one core: the signal of
// fixtures/scenarios/perf-1e7.json (paper-d2-analog at 106.7 Hz electrical, 100 kHz, noise),
// 2^21 samples pre-generated with truth and atan2's estimates outside the timed loop, fed in
// the run engine's blocks of 16384 to a fresh analyser each iteration (as a run of that length).
// The run's harness cost (perf/harness_ratio.sh) is these plus the source and the estimators.
//   build/perf/bench_analysers            the benchmarks (items = samples)
//   build/perf/bench_analysers --dump     each analyser's results as JSON, for checking that a
//                                         faster version computes the same figures
//   build/perf/bench_analysers --run NAME K   NAME (truth, conventions, spectrum, signal_quality,
//                                         traces) K times and nothing else: for `perf stat -e
//                                         cycles:u` on a busy machine, where times mislead
#include "estimator/estimator.hpp"
#include "server/analysis/analyser.hpp"
#include "server/analysis/scoring.hpp"
#include "server/analysis/signal_quality.hpp"
#include "server/analysis/spectrum.hpp"
#include "server/analysis/traces.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/generator.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <limits>

using namespace fringe;

namespace {

constexpr std::size_t kSamples = std::size_t{1} << 21, kBlock = 16384;

struct Lane {
    double fs = 0;
    Block b;
    std::vector<double> th, om, err;
    std::vector<std::uint8_t> valid, known;
};

const Lane& lane() {
    static const Lane l = [] {
        Lane o;
        const auto sc = load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/perf-1e7.json");
        o.fs = sc.sample_rate_hz;
        Generator g(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed);
        o.b.resize(kSamples, false);
        g.generate(0, o.b);
        est::EstimatorConfig cfg;
        cfg.sample_rate_hz = sc.sample_rate_hz;
        cfg.encoder = sc.encoder;
        auto e = est::make("atan2", cfg);
        o.th.resize(kSamples);
        o.om.resize(kSamples);
        o.valid.resize(kSamples);
        e->process({o.b.sin_v, o.b.cos_v}, {o.th, o.om, o.valid});
        o.known.assign(kSamples, 1);
        o.err.resize(kSamples);
        for (std::size_t i = 0; i < kSamples; ++i)
            o.err[i] = o.valid[i] ? o.th[i] - o.b.theta_rad[i] : std::numeric_limits<double>::quiet_NaN();
        return o;
    }();
    return l;
}

LaneBlock block_at(const Lane& l, std::size_t at, std::size_t n) {
    LaneBlock b;
    b.n = n;
    b.t_s = l.b.t_s.data() + at;
    b.sin_v = l.b.sin_v.data() + at;
    b.cos_v = l.b.cos_v.data() + at;
    b.theta_true_rad = l.b.theta_rad.data() + at;
    b.omega_true_rad_s = l.b.omega_rad_s.data() + at;
    b.truth_known = l.known.data() + at;
    b.theta_hat_rad = l.th.data() + at;
    b.omega_hat_rad_s = l.om.data() + at;
    b.valid = l.valid.data() + at;
    return b;
}

LaneContext context(const Lane& l) {
    LaneContext c;
    c.sample_rate_hz = l.fs;
    c.settle_s = 0.1;
    c.spectrum_segment = ErrorSpectrum::choose_segment(l.fs, 106.72358591248666, 10000000);
    return c;
}

// Every block of the lane through f(at, n).
template <class F>
void blocks(F&& f) {
    for (std::size_t at = 0; at < kSamples; at += kBlock) f(at, std::min(kBlock, kSamples - at));
}

// A registered analyser by name, through the registry (as the engine makes it).
nlohmann::json run_analyser(const std::string& name) {
    const Lane& l = lane();
    for (const auto& info : analyser_registry()) {
        if (info.name != name) continue;
        auto a = info.make(context(l));
        blocks([&](std::size_t at, std::size_t n) { a->add(block_at(l, at, n)); });
        LaneResults r;
        a->finish(r);
        if (r.error) return to_json(*r.error, 0);
        if (!r.spectrum.is_null()) return r.spectrum;
        nlohmann::json j = nlohmann::json::array();
        for (const auto& f : r.conventions) j.push_back({f.code, f.message});
        return j;
    }
    throw std::invalid_argument("no analyser " + name);
}

nlohmann::json run_signal_quality() {
    const Lane& l = lane();
    SignalQuality q;
    blocks([&](std::size_t at, std::size_t n) { q.add(l.b.t_s.data() + at, l.b.sin_v.data() + at, l.b.cos_v.data() + at, n); });
    return q.to_json();
}

nlohmann::json run_traces() {
    const Lane& l = lane();
    TraceRecorder tr(kSamples, 2000, {"atan2"}, 0.1);
    blocks([&](std::size_t at, std::size_t n) {
        tr.add(n, l.b.t_s.data() + at, l.b.sin_v.data() + at, l.b.cos_v.data() + at, l.b.theta_rad.data() + at, l.known.data() + at,
               {l.err.data() + at});
    });
    return tr.to_json();
}

void timed(benchmark::State& state, nlohmann::json (*f)()) {
    lane();
    for (auto _ : state) benchmark::DoNotOptimize(f());
    state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * kSamples));
}

void BM_truth(benchmark::State& s) { timed(s, [] { return run_analyser("truth"); }); }
void BM_conventions(benchmark::State& s) { timed(s, [] { return run_analyser("conventions"); }); }
void BM_spectrum(benchmark::State& s) { timed(s, [] { return run_analyser("spectrum"); }); }
void BM_signal_quality(benchmark::State& s) { timed(s, run_signal_quality); }
void BM_traces(benchmark::State& s) { timed(s, run_traces); }

}  // namespace

BENCHMARK(BM_truth)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_conventions)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_spectrum)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_signal_quality)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_traces)->Unit(benchmark::kMillisecond);

int main(int argc, char** argv) {
    if (argc > 1 && std::strcmp(argv[1], "--dump") == 0) {
        nlohmann::json out{{"truth", run_analyser("truth")},
                           {"conventions", run_analyser("conventions")},
                           {"spectrum", run_analyser("spectrum")},
                           {"signal_quality", run_signal_quality()},
                           {"traces", run_traces()}};
        std::cout << out.dump(1) << "\n";
        return 0;
    }
    if (argc > 3 && std::strcmp(argv[1], "--run") == 0) {
        const std::string name = argv[2];
        const int k = std::atoi(argv[3]);
        lane();
        for (int i = 0; i < k; ++i) {
            if (name == "signal_quality") benchmark::DoNotOptimize(run_signal_quality());
            else if (name == "traces") benchmark::DoNotOptimize(run_traces());
            else benchmark::DoNotOptimize(run_analyser(name));
        }
        return 0;
    }
    benchmark::Initialize(&argc, argv);
    benchmark::RunSpecifiedBenchmarks();
    benchmark::Shutdown();
    return 0;
}
