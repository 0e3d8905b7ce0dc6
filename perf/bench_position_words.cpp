// Position-word decoders' throughput (docs/dut-readouts.md): logic samples per second on one
// core for SSI, BiSS-C and SPI, on a trace their emitters wrote (4 samples per clock period, as
// a logic analyser at 4x the clock). Run: build/perf/bench_position_words
#include "drivers/position_words.hpp"

#include <benchmark/benchmark.h>

#include <type_traits>
#include <vector>

using namespace fringe;

namespace {

EmitterTiming timing() {
    EmitterTiming tm;
    tm.sample_rate_hz = 24e6;  // an fx2lafw logic analyser's top rate
    tm.half_clock_samples = 2;
    tm.idle_samples = 24;
    return tm;
}

template <class Decoder, class Config, class Emit>
void run(benchmark::State& state, const Config& c, Emit emit) {
    LogicSignals s;
    for (std::uint64_t k = 0; k < 2000; ++k) emit(c, timing(), (k * 2654435761u) & 0xFFFFF, WordFault{}, s);
    std::vector<PositionWord> out;
    out.reserve(4096);
    const std::size_t n = s.t_s.size();
    std::uint64_t words = 0;
    for (auto _ : state) {
        Decoder d(c);
        out.clear();
        if constexpr (std::is_same_v<Decoder, SpiDecoder>)
            d.process(n, s.t_s.data(), s.cs.data(), s.clk.data(), s.data.data(), out);
        else
            d.process(n, s.t_s.data(), s.clk.data(), s.data.data(), out);
        d.finish(out);
        words += out.size();
        benchmark::DoNotOptimize(out.data());
    }
    state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * n));
    state.counters["words_per_s"] = benchmark::Counter(static_cast<double>(words), benchmark::Counter::kIsRate);
}

void BM_ssi_25bit(benchmark::State& state) {
    SsiConfig c;
    c.position_bits = 25;
    c.timeout_s = 1e-6;
    run<SsiDecoder>(state, c, [](auto&&... a) { return emit_ssi_frame(a...); });
}
void BM_biss_32bit(benchmark::State& state) {
    BissConfig c;
    c.position_bits = 32;
    c.timeout_s = 1e-6;
    run<BissDecoder>(state, c, [](auto&&... a) { return emit_biss_frame(a...); });
}
void BM_spi_16bit_mode1(benchmark::State& state) {
    SpiConfig c;
    c.mode = 1;
    c.word_bits = 16;
    run<SpiDecoder>(state, c, [](auto&&... a) { return emit_spi_frame(a...); });
}

}  // namespace

BENCHMARK(BM_ssi_25bit);
BENCHMARK(BM_biss_32bit);
BENCHMARK(BM_spi_16bit_mode1);
BENCHMARK_MAIN();
