// ekf-auto throughput, samples/s on one core, over a long continuous signal: the paper's 1.6 %
// duty-cycle signal (fixtures/scenarios/paper-duty1p6.json, 16-bit ADC, noise), 2^21 samples
// (21 s at 100 kHz) generated once outside the timed loop. bench_estimators repeats one
// 65536-sample block; the phase jump where it wraps is a new signal to ekf-auto, which then
// re-acquires and replays every block. Here the signal is continuous:
//   steady: a fresh estimator learns the first 2^19 samples untimed, then the rest is timed
//           in 65536-sample blocks (tracking and learning, as in a long run);
//   capture: a fresh estimator over all 2^21 samples, acquisition and replays included (a
//           user's capture as handed to `fringe estimate`).
#include "estimator/estimator.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/generator.hpp"

#include <benchmark/benchmark.h>

#include <algorithm>

using namespace fringe;

namespace {

constexpr std::size_t kTotal = std::size_t{1} << 21;
constexpr std::size_t kBlock = 65536;
constexpr std::size_t kWarm = std::size_t{1} << 19;

struct Signal {
    std::vector<double> s, c;
    EncoderProfile enc;
    double fs = 0;
};

const Signal& paper_long() {
    static const Signal sig = [] {
        const auto sc = load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/paper-duty1p6.json");
        Signal out;
        out.enc = sc.encoder;
        out.fs = sc.sample_rate_hz;
        Generator g(sc.encoder, sc.motion, sc.sample_rate_hz, sc.seed);
        Block b;
        b.resize(kBlock, false);
        for (std::size_t first = 0; first < kTotal; first += kBlock) {
            g.generate(first, b);
            out.s.insert(out.s.end(), b.sin_v.begin(), b.sin_v.end());
            out.c.insert(out.c.end(), b.cos_v.begin(), b.cos_v.end());
        }
        return out;
    }();
    return sig;
}

std::unique_ptr<est::Estimator> fresh(const Signal& s) {
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = s.fs;
    cfg.encoder = s.enc;
    cfg.params = nlohmann::json::object();
    return est::make("ekf-auto", cfg);
}

// [from, to) in kBlock-sample blocks
void run_range(est::Estimator& e, const Signal& s, std::size_t from, std::size_t to, std::vector<double>& th, std::vector<double>& om,
               std::vector<std::uint8_t>& v) {
    for (std::size_t i = from; i < to; i += kBlock) {
        const std::size_t n = std::min(kBlock, to - i);
        e.process({std::span<const double>(s.s.data() + i, n), std::span<const double>(s.c.data() + i, n)},
                  {std::span<double>(th.data(), n), std::span<double>(om.data(), n), std::span<std::uint8_t>(v.data(), n)});
        benchmark::DoNotOptimize(th.data());
        benchmark::ClobberMemory();
    }
}

void steady(benchmark::State& state) {
    const Signal& s = paper_long();
    std::vector<double> th(kBlock), om(kBlock);
    std::vector<std::uint8_t> v(kBlock);
    for (auto _ : state) {
        state.PauseTiming();
        auto e = fresh(s);
        run_range(*e, s, 0, kWarm, th, om, v);
        state.ResumeTiming();
        run_range(*e, s, kWarm, kTotal, th, om, v);
    }
    state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * (kTotal - kWarm)));
}

void capture(benchmark::State& state) {
    const Signal& s = paper_long();
    std::vector<double> th(kBlock), om(kBlock);
    std::vector<std::uint8_t> v(kBlock);
    for (auto _ : state) {
        auto e = fresh(s);
        run_range(*e, s, 0, kTotal, th, om, v);
    }
    state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * kTotal));
}

}  // namespace

BENCHMARK(steady)->Unit(benchmark::kMillisecond);
BENCHMARK(capture)->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();
