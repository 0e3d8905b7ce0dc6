// fringe's position-word emitters and decoders on files, for the peer test against sigrok's
// spi decoder (tests/cli_position_words.sh, docs/dut-readouts.md):
//   emit spi MODE BITS msb|lsb COUNT SEED OUT.csv   CSV cs,clk,data; stdout: "value latch_sample" per frame
//   emit ssi BITS binary|gray COUNT SEED OUT.csv    CSV clk,data; the same stdout
//   decode spi MODE BITS msb|lsb IN.sr              stdout: "valid value latch_sample" per word, then "stats JSON"
//   decode ssi BITS binary|gray IN.sr
// SPI frames 5, 17, 29, ... lose a clock pulse (a short frame: no word for either decoder);
// frames 3, 15, 27, ... have one bit flipped (both decoders read the flipped value).
#include "drivers/position_words.hpp"
#include "drivers/sigrok_file.hpp"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <algorithm>
#include <map>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

using namespace fringe;

namespace {

constexpr double kRateHz = 1e6;

[[noreturn]] void usage() {
    std::fprintf(stderr,
                 "usage: position_words_tool emit spi MODE BITS msb|lsb COUNT SEED OUT.csv\n"
                 "       position_words_tool emit ssi BITS binary|gray COUNT SEED OUT.csv\n"
                 "       position_words_tool decode spi MODE BITS msb|lsb IN.sr\n"
                 "       position_words_tool decode ssi BITS binary|gray IN.sr\n");
    std::exit(2);
}

std::uint64_t mask(int bits) { return bits >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << bits) - 1; }

// Values that visit both ends of the range, then random ones.
std::vector<std::uint64_t> values(int bits, int count, unsigned seed) {
    std::mt19937_64 rng(seed);
    const std::uint64_t m = mask(bits);
    std::vector<std::uint64_t> v = {0, m, 1 & m, m - 1, m >> 1, (m >> 1) + 1};
    while (static_cast<int>(v.size()) < count) v.push_back(rng() & m);
    v.resize(static_cast<std::size_t>(count));
    return v;
}

SpiConfig spi_config(const std::string& mode, const std::string& bits, const std::string& order) {
    SpiConfig c;
    c.mode = std::stoi(mode);
    c.word_bits = std::stoi(bits);
    if (order != "msb" && order != "lsb") usage();
    c.msb_first = order == "msb";
    return c;
}

SsiConfig ssi_config(const std::string& bits, const std::string& code) {
    SsiConfig c;
    c.position_bits = std::stoi(bits);
    if (code != "binary" && code != "gray") usage();
    c.code = code == "gray" ? WordCode::gray : WordCode::binary;
    c.timeout_s = 20e-6;
    return c;
}

void write_csv(const std::string& path, const LogicSignals& s, bool with_cs) {
    std::ofstream f(path);
    f << (with_cs ? "cs,clk,data\n" : "clk,data\n");
    for (std::size_t i = 0; i < s.t_s.size(); ++i) {
        if (with_cs) f << (s.cs[i] != 0 ? '1' : '0') << ',';
        f << (s.clk[i] != 0 ? '1' : '0') << ',' << (s.data[i] != 0 ? '1' : '0') << '\n';
    }
    if (!f) throw std::runtime_error("cannot write " + path);
}

long long sample_of(double t_s) { return std::llround(t_s * kRateHz); }

int emit(const std::vector<std::string>& a) {
    const bool spi = a[1] == "spi";
    if (spi ? a.size() != 8 : a.size() != 7) usage();
    const std::size_t k = spi ? 3 : 2;
    const int count = std::stoi(a[k + 2]);
    const unsigned seed = static_cast<unsigned>(std::stoul(a[k + 3]));
    EmitterTiming tm;
    tm.sample_rate_hz = kRateHz;
    tm.half_clock_samples = 2;
    tm.idle_samples = 30;
    LogicSignals s;
    if (spi) {
        const SpiConfig c = spi_config(a[2], a[3], a[4]);
        for (int i = 0; const std::uint64_t v : values(c.word_bits, count, seed)) {
            WordFault f;
            if (i % 12 == 5) f.drop_clock = i % c.word_bits;
            if (i % 12 == 3) f.flip_bit = i % c.word_bits;
            const double latch = emit_spi_frame(c, tm, v, f, s);
            std::printf("%llu %lld\n", static_cast<unsigned long long>(v), sample_of(latch));
            ++i;
        }
        emit_idle(tm, 10, s);
    } else {
        const SsiConfig c = ssi_config(a[2], a[3]);
        for (const std::uint64_t v : values(c.position_bits, count, seed)) {
            const double latch = emit_ssi_frame(c, tm, v, WordFault{}, s);
            std::printf("%llu %lld\n", static_cast<unsigned long long>(v), sample_of(latch));
        }
        emit_idle(tm, 10, s);
    }
    write_csv(a.back(), s, spi);
    return 0;
}

int decode(const std::vector<std::string>& a) {
    const bool spi = a[1] == "spi";
    if (spi ? a.size() != 6 : a.size() != 5) usage();
    // The session's channels clk, data (and cs) through the logic columns a, b (and z).
    std::map<std::string, std::string> ch = {{"a", "clk"}, {"b", "data"}};
    if (spi) ch["z"] = "cs";
    SigrokSession sr(a.back(), ch, std::uint64_t{1} << 30);
    if (sr.sample_rate_hz() != kRateHz) throw std::runtime_error("unexpected sample rate");
    std::vector<PositionWord> words;
    nlohmann::json stats;
    SpiDecoder* spi_dec = nullptr;
    SsiDecoder* ssi_dec = nullptr;
    std::unique_ptr<SpiDecoder> spi_owner;
    std::unique_ptr<SsiDecoder> ssi_owner;
    if (spi) spi_dec = (spi_owner = std::make_unique<SpiDecoder>(spi_config(a[2], a[3], a[4]))).get();
    else ssi_dec = (ssi_owner = std::make_unique<SsiDecoder>(ssi_config(a[2], a[3]))).get();
    std::uint64_t done = 0;
    while (done < sr.frames()) {  // blocks of 4099 samples: frames straddle the blocks
        const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(4099, sr.frames() - done));
        std::map<std::string, std::vector<double>> cols;
        sr.read(n, cols);
        std::vector<double> t(n);
        for (std::size_t i = 0; i < n; ++i) t[i] = static_cast<double>(done + i) / kRateHz;
        if (spi) spi_dec->process(n, t.data(), cols["z"].data(), cols["a"].data(), cols["b"].data(), words);
        else ssi_dec->process(n, t.data(), cols["a"].data(), cols["b"].data(), words);
        done += n;
    }
    if (spi) {
        spi_dec->finish(words);
        stats = spi_dec->to_json();
    } else {
        ssi_dec->finish(words);
        stats = ssi_dec->to_json();
    }
    for (const PositionWord& w : words)
        std::printf("%d %llu %lld\n", w.valid ? 1 : 0, static_cast<unsigned long long>(w.value), sample_of(w.t_s));
    std::printf("stats %s\n", stats.dump().c_str());
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    const std::vector<std::string> a(argv + 1, argv + argc);
    if (a.size() < 2 || (a[1] != "spi" && a[1] != "ssi")) usage();
    try {
        if (a[0] == "emit") return emit(a);
        if (a[0] == "decode") return decode(a);
    } catch (const std::exception& e) {
        std::fprintf(stderr, "position_words_tool: %s\n", e.what());
        return 2;
    }
    usage();
}
