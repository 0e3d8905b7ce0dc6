// Signal generator throughput: sample pairs (sin, cos + truth) per second on one core,
// with noise and ADC, without file I/O. Run: build/perf/bench_signal_gen
#include "server/engine/scenario.hpp"
#include "signal_gen/generator.hpp"

#include <benchmark/benchmark.h>

using namespace fringe;

namespace {
const std::string kSrc = FRINGE_SOURCE_DIR;

void run(benchmark::State& state, EncoderProfile enc, const std::string& scenario = "paper-duty1p6.json") {
    Scenario sc = load_scenario(kSrc + "/fixtures/scenarios/" + scenario);
    Generator gen(std::move(enc), sc.motion, sc.sample_rate_hz, 1);
    const std::size_t n = static_cast<std::size_t>(state.range(0));
    Block b;
    b.resize(n, false);
    std::uint64_t k = 0;
    for (auto _ : state) {
        gen.generate(k, b);
        benchmark::DoNotOptimize(b.sin_v.data());
        benchmark::ClobberMemory();
        k += n;
    }
    state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()) * state.range(0));
}

void BM_paper_diffraction(benchmark::State& state) {
    run(state, load_encoder(kSrc + "/fixtures/encoders/paper-d2-duty1p6.json"));
}
// The encoder and motion of perf-1e7.json (perf/harness_ratio.sh: the generator's own time).
void BM_perf_1e7(benchmark::State& state) {
    const Scenario sc = load_scenario(kSrc + "/fixtures/scenarios/perf-1e7.json");
    run(state, sc.encoder, "perf-1e7.json");
}
void BM_ideal(benchmark::State& state) {
    run(state, load_encoder(kSrc + "/fixtures/encoders/ideal.json"));
}
void BM_diffraction_runout_eccentricity(benchmark::State& state) {
    EncoderProfile e = load_encoder(kSrc + "/fixtures/encoders/paper-d2-duty1p6.json");
    e.gap_d1_cm = 0.747;
    e.e1_cm = 0.001;
    run(state, e);
}
}  // namespace

BENCHMARK(BM_paper_diffraction)->Arg(4096)->Arg(65536);
BENCHMARK(BM_ideal)->Arg(65536);
BENCHMARK(BM_perf_1e7)->Arg(65536);
BENCHMARK(BM_diffraction_runout_eccentricity)->Arg(65536);
BENCHMARK_MAIN();
