// Position-word readouts of a DUT (docs/dut-readouts.md): SSI, BiSS-C and SPI decoders against
// their emitters at the edges of every range, BiSS CRC6 against hand-computed remainders, every
// wire fault counted and invalidating exactly its word, blocks split at every sample, hostile
// input, the angle mapping against its closed form, and the line-oriented position stream.
#include "drivers/position_words.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <random>
#include <type_traits>
#include <string>
#include <vector>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_position_words_cpp {

using namespace fringe;

namespace {

constexpr double kTwoPiT = 6.283185307179586;

std::uint64_t mask(int bits) { return bits >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << bits) - 1; }

// Both ends of the range, the middle, and a few random values.
std::vector<std::uint64_t> edge_values(int bits, unsigned seed) {
    const std::uint64_t m = mask(bits);
    std::vector<std::uint64_t> v = {0, m, 1 & m, m - 1, m >> 1, (m >> 1) + 1, 0x5555555555555555ull & m, 0xAAAAAAAAAAAAAAAAull & m};
    std::mt19937_64 rng(seed);
    for (int k = 0; k < 4; ++k) v.push_back(rng() & m);
    return v;
}

EmitterTiming timing() {
    EmitterTiming tm;
    tm.sample_rate_hz = 1e6;
    tm.half_clock_samples = 2;
    tm.idle_samples = 30;
    return tm;
}

// Decodes s with `split` block boundaries (sample indices, ascending), then finish().
template <class Decoder>
std::vector<PositionWord> run(Decoder& d, const LogicSignals& s, const std::vector<std::size_t>& split = {}) {
    std::vector<PositionWord> out;
    std::size_t from = 0;
    std::vector<std::size_t> cuts = split;
    cuts.push_back(s.t_s.size());
    for (std::size_t to : cuts) {
        const std::size_t n = to - from;
        if constexpr (std::is_same_v<Decoder, SpiDecoder>)
            d.process(n, s.t_s.data() + from, s.cs.data() + from, s.clk.data() + from, s.data.data() + from, out);
        else
            d.process(n, s.t_s.data() + from, s.clk.data() + from, s.data.data() + from, out);
        from = to;
    }
    d.finish(out);
    return out;
}

// Every word valid, with the value sent and stamped at the emitter's latch time.
void round_trip(const std::vector<PositionWord>& w, const std::vector<std::uint64_t>& vals, const std::vector<double>& latch) {
    REQUIRE(w.size() == vals.size());
    for (std::size_t i = 0; i < w.size(); ++i) {
        CHECK(w[i].valid);
        CHECK(w[i].value == vals[i]);
        CHECK(w[i].t_s == latch[i]);
    }
}

void same_words(const std::vector<PositionWord>& a, const std::vector<PositionWord>& b) {
    REQUIRE(a.size() == b.size());
    for (std::size_t i = 0; i < a.size(); ++i) {
        CHECK(a[i].t_s == b[i].t_s);
        CHECK(a[i].value == b[i].value);
        CHECK(a[i].valid == b[i].valid);
        CHECK(a[i].error == b[i].error);
        if (a[i].valid) CHECK(a[i].theta_rad == b[i].theta_rad);
    }
}

}  // namespace

TEST_CASE("Gray code round trips over the whole 64-bit range", "[dut][words]") {
    // closed forms: gray(b) = b ^ (b >> 1); consecutive values differ in one bit
    CHECK(binary_to_gray(0) == 0);
    CHECK(binary_to_gray(1) == 1);
    CHECK(binary_to_gray(2) == 3);
    CHECK(binary_to_gray(5) == 7);
    CHECK(binary_to_gray(~std::uint64_t{0}) == (std::uint64_t{1} << 63));
    CHECK(gray_to_binary(std::uint64_t{1} << 63) == ~std::uint64_t{0});
    for (int bits = 1; bits <= 64; ++bits)
        for (std::uint64_t v : edge_values(bits, static_cast<unsigned>(bits))) {
            CHECK(gray_to_binary(binary_to_gray(v)) == v);
            if (v != mask(bits)) CHECK(__builtin_popcountll(binary_to_gray(v) ^ binary_to_gray(v + 1)) == 1);
        }
}

TEST_CASE("BiSS CRC6 (x^6+x+1) equals the remainders computed by hand", "[dut][words]") {
    // The CRC is the remainder of m(x) * x^6 divided by P(x) = x^6 + x + 1. Reduction table:
    // x^6 = x+1, x^7 = x^2+x, x^8 = x^3+x^2, x^9 = x^4+x^3, x^10 = x^5+x^4, x^11 = x^5+x+1,
    // x^12 = x^2+1, x^13 = x^3+x, x^15 = x^5+x^3, x^17 = x^5+x^2+x, x^19 = x^4+x^3+x^2+x.
    auto crc = [](const std::string& bits) {
        std::vector<std::uint8_t> b;
        for (char c : bits) b.push_back(c == '1' ? 1 : 0);
        return biss_crc6(b.data(), b.size());
    };
    CHECK(crc("") == 0);
    CHECK(crc("000000000") == 0);   // zeros divide to nothing
    CHECK(crc("1") == 0x03);        // x^6 = x + 1
    CHECK(crc("10") == 0x06);       // x^7 = x^2 + x
    CHECK(crc("100000") == 0x23);   // x^11 = x^5 + x + 1
    CHECK(crc("1000000") == 0x05);  // x^12 = (x+1)^2 = x^2 + 1
    CHECK(crc("1101") == 0x17);     // x^9+x^8+x^6 = (x^4+x^3)+(x^3+x^2)+(x+1) = x^4+x^2+x+1
    CHECK(crc("111111") == 0x02);   // x^6..x^11 sum to x
    // A 12-bit position 0xABC with nE = nW = 1: m = 1010 1011 1100 11, m*x^6 has the terms
    // x^19,17,15,13,12,11,10,7,6; by the table they sum to x^3 + 1 = 0x09 (sent inverted: 0x36).
    CHECK(crc("10101011110011") == 0x09);
    // the register leading zeros do not change it; the message followed by its CRC divides exactly
    CHECK(crc("00010101011110011") == 0x09);
    CHECK(crc("10101011110011" "001001") == 0);
}

TEST_CASE("SSI words round-trip at the edges of every range, binary and Gray", "[dut][words]") {
    const EmitterTiming tm = timing();
    for (int bits : {1, 2, 12, 13, 25, 31, 32, 33, 63, 64})
        for (WordCode code : {WordCode::binary, WordCode::gray})
            for (int error_bits : {0, 1, 2}) {
                CAPTURE(bits, code == WordCode::gray, error_bits);
                SsiConfig c;
                c.position_bits = bits;
                c.code = code;
                c.error_bits = error_bits;
                c.error_active_high = error_bits != 2;  // active low: the status bits sent are 1
                LogicSignals s;
                std::vector<double> latch;
                const auto vals = edge_values(bits, static_cast<unsigned>(bits * 7 + error_bits));
                for (std::uint64_t v : vals) latch.push_back(emit_ssi_frame(c, tm, v, {}, s));
                SsiDecoder d(c);
                const auto w = run(d, s);
                round_trip(w, vals, latch);
                CHECK(d.stats().valid_words == vals.size());
                CHECK(d.stats().invalid_words == 0);
            }
}

TEST_CASE("BiSS-C words round-trip at the edges of every range, CRC checked", "[dut][words]") {
    for (int bits : {1, 2, 12, 18, 26, 32, 36, 63, 64})
        for (int ack : {1, 3, 10})
            for (WordCode code : {WordCode::binary, WordCode::gray}) {
                CAPTURE(bits, ack, code == WordCode::gray);
                EmitterTiming tm = timing();
                tm.ack_bits = ack;
                BissConfig c;
                c.position_bits = bits;
                c.code = code;
                LogicSignals s;
                std::vector<double> latch;
                const auto vals = edge_values(bits, static_cast<unsigned>(bits + ack));
                for (std::uint64_t v : vals) latch.push_back(emit_biss_frame(c, tm, v, {}, s));
                BissDecoder d(c);
                const auto w = run(d, s);
                round_trip(w, vals, latch);
                CHECK(d.stats().crc_errors == 0);
                CHECK(d.stats().invalid_words == 0);
            }
}

TEST_CASE("BiSS-C emitter puts the hand-computed CRC on the wire", "[dut][words]") {
    // 12-bit 0xABC, nE = nW = 1: CRC 0x09, sent inverted 0x36 = 110110 (see the CRC6 test).
    EmitterTiming tm = timing();
    BissConfig c;
    c.position_bits = 12;
    LogicSignals s;
    emit_biss_frame(c, tm, 0xABC, {}, s);
    // read SLO at the falling edges of MA, after the start bit
    std::vector<int> bits;
    bool start = false, ack = false;
    for (std::size_t i = 1; i < s.t_s.size(); ++i)
        if (s.clk[i] == 0 && s.clk[i - 1] != 0) {
            const int d = s.data[i] != 0;
            if (start) bits.push_back(d);
            else if (!ack && !d) ack = true;
            else if (ack && d) start = true;
        }
    REQUIRE(bits.size() == 1 + 12 + 2 + 6);
    std::string got;
    for (int b : bits) got += static_cast<char>('0' + b);
    CHECK(got == "0" "101010111100" "11" "110110");  // CDS, data, nE, nW, ~CRC
}

TEST_CASE("SPI words round-trip in every mode, MSB and LSB first, 1..64 bits", "[dut][words]") {
    const EmitterTiming tm = timing();
    for (int mode = 0; mode < 4; ++mode)
        for (bool msb : {true, false})
            for (int bits : {1, 2, 8, 16, 24, 31, 32, 33, 63, 64}) {
                CAPTURE(mode, msb, bits);
                SpiConfig c;
                c.mode = mode;
                c.word_bits = bits;
                c.msb_first = msb;
                LogicSignals s;
                std::vector<double> latch;
                const auto vals = edge_values(bits, static_cast<unsigned>(mode * 64 + bits));
                for (std::uint64_t v : vals) latch.push_back(emit_spi_frame(c, tm, v, {}, s));
                SpiDecoder d(c);
                const auto w = run(d, s);
                round_trip(w, vals, latch);
            }
}

TEST_CASE("SPI bit order: MSB first sends the word's top bit first, LSB first its bit 0", "[dut][words]") {
    // Read the data line at the sampling edges directly: 0b1101 0000 0001 in 12 bits, mode 0.
    const EmitterTiming tm = timing();
    for (bool msb : {true, false}) {
        SpiConfig c;
        c.word_bits = 12;
        c.msb_first = msb;
        LogicSignals s;
        emit_spi_frame(c, tm, 0xD01, {}, s);
        std::string got;
        for (std::size_t i = 1; i < s.t_s.size(); ++i)
            if (s.cs[i] == 0 && s.clk[i] != 0 && s.clk[i - 1] == 0) got += s.data[i] != 0 ? '1' : '0';
        CHECK(got == (msb ? "110100000001" : "100000001011"));
    }
}

TEST_CASE("SPI position field, error bit and Gray code inside a word", "[dut][words]") {
    // An interpolator-style 16-bit word: bit 15 unused, bit 14 error (active high), 14 position bits.
    const EmitterTiming tm = timing();
    SpiConfig c;
    c.mode = 1;
    c.word_bits = 16;
    c.position_bits = 14;
    c.error_bit = 14;
    c.code = WordCode::gray;
    LogicSignals s;
    for (std::uint64_t v : {0ull, 16383ull, 1234ull}) emit_spi_frame(c, tm, v, {}, s);
    WordFault err;
    err.set_error = true;
    emit_spi_frame(c, tm, 77, err, s);
    SpiDecoder d(c);
    const auto w = run(d, s);
    REQUIRE(w.size() == 4);
    CHECK(w[0].value == 0);
    CHECK(w[1].value == 16383);
    CHECK(w[2].value == 1234);
    CHECK(!w[3].valid);
    CHECK(w[3].error == "error_flag");
    CHECK(d.stats().error_flags == 1);
    CHECK_THROWS_AS(SpiDecoder([] { SpiConfig b; b.word_bits = 16; b.position_bits = 15; b.error_bit = 3; return b; }()), std::invalid_argument);
    CHECK_THROWS_AS(SpiDecoder([] { SpiConfig b; b.word_bits = 65; return b; }()), std::invalid_argument);
    CHECK_THROWS_AS(SpiDecoder([] { SpiConfig b; b.word_bits = 8; b.mode = 4; return b; }()), std::invalid_argument);
}

namespace {

// Eleven frames, frame 4 carries the fault: exactly that word is invalid with `cause`, the
// counter says 1, and every other word is read right.
template <class Config, class Decoder, class Emit>
void one_fault(const Config& c, Emit emit, const WordFault& f, const std::string& cause, std::uint64_t PositionWordStats::*counter,
               const EmitterTiming& tm = timing()) {
    LogicSignals s;
    std::vector<std::uint64_t> vals;
    for (int i = 0; i < 11; ++i) {
        vals.push_back(static_cast<std::uint64_t>(i * 37 + 5));
        emit(c, tm, vals.back(), i == 4 ? f : WordFault{}, s);
    }
    Decoder d(c);
    const auto w = run(d, s);
    REQUIRE(w.size() == 11);
    for (std::size_t i = 0; i < w.size(); ++i) {
        CAPTURE(i);
        if (i == 4) {
            CHECK(!w[i].valid);
            CHECK(std::isnan(w[i].theta_rad));
            CHECK(w[i].error == cause);
        } else {
            CHECK(w[i].valid);
            CHECK(w[i].value == vals[i]);
        }
    }
    CHECK(d.stats().*counter == 1);
    CHECK(d.stats().invalid_words == 1);
    CHECK(d.stats().valid_words == 10);
}

}  // namespace

TEST_CASE("SSI faults: each is counted and invalidates exactly its word", "[dut][words]") {
    SsiConfig c;
    c.position_bits = 13;
    c.error_bits = 1;
    auto emit = [](const SsiConfig& k, const EmitterTiming& tm, std::uint64_t v, const WordFault& f, LogicSignals& s) {
        return emit_ssi_frame(k, tm, v, f, s);
    };
    WordFault f;
    SECTION("a dropped clock") { f.drop_clock = 6; one_fault<SsiConfig, SsiDecoder>(c, emit, f, "short_frame", &PositionWordStats::short_frames); }
    SECTION("the first clock dropped") { f.drop_clock = 0; one_fault<SsiConfig, SsiDecoder>(c, emit, f, "short_frame", &PositionWordStats::short_frames); }
    SECTION("an extra clock") { f.extra_clocks = 1; one_fault<SsiConfig, SsiDecoder>(c, emit, f, "long_frame", &PositionWordStats::long_frames); }
    SECTION("the error bit") { f.set_error = true; one_fault<SsiConfig, SsiDecoder>(c, emit, f, "error_flag", &PositionWordStats::error_flags); }
    SECTION("not ready") { f.not_ready = true; one_fault<SsiConfig, SsiDecoder>(c, emit, f, "not_ready", &PositionWordStats::not_ready); }
}

TEST_CASE("SSI has no check: a flipped bit is read as sent, and only that word differs", "[dut][words]") {
    SsiConfig c;
    c.position_bits = 13;
    const EmitterTiming tm = timing();
    LogicSignals s;
    WordFault f;
    f.flip_bit = 0;  // the MSB
    for (int i = 0; i < 5; ++i) emit_ssi_frame(c, tm, 100, i == 2 ? f : WordFault{}, s);
    SsiDecoder d(c);
    const auto w = run(d, s);
    REQUIRE(w.size() == 5);
    for (std::size_t i = 0; i < 5; ++i) CHECK(w[i].value == (i == 2 ? 100u + 4096u : 100u));
    CHECK(d.stats().invalid_words == 0);
}

TEST_CASE("BiSS-C faults: each is counted and invalidates exactly its word", "[dut][words]") {
    BissConfig c;
    c.position_bits = 18;
    auto emit = [](const BissConfig& k, const EmitterTiming& tm, std::uint64_t v, const WordFault& f, LogicSignals& s) {
        return emit_biss_frame(k, tm, v, f, s);
    };
    WordFault f;
    SECTION("a data bit flipped: bad CRC") { f.flip_bit = 5; one_fault<BissConfig, BissDecoder>(c, emit, f, "crc", &PositionWordStats::crc_errors); }
    SECTION("a CRC bit flipped") { f.flip_bit = 1 + 18 + 2 + 5; one_fault<BissConfig, BissDecoder>(c, emit, f, "crc", &PositionWordStats::crc_errors); }
    SECTION("nE flipped without its CRC") { f.flip_bit = 1 + 18; one_fault<BissConfig, BissDecoder>(c, emit, f, "crc", &PositionWordStats::crc_errors); }
    SECTION("a dropped clock") { f.drop_clock = 9; one_fault<BissConfig, BissDecoder>(c, emit, f, "short_frame", &PositionWordStats::short_frames); }
    // the last of ack_bits + L + 3 pulses, L = 1 + 18 + 2 + 6
    SECTION("the last clock dropped") { f.drop_clock = 1 + 27 + 3 - 1; one_fault<BissConfig, BissDecoder>(c, emit, f, "short_frame", &PositionWordStats::short_frames); }
    SECTION("an extra clock") { f.extra_clocks = 1; one_fault<BissConfig, BissDecoder>(c, emit, f, "long_frame", &PositionWordStats::long_frames); }
    SECTION("the error bit nE") { f.set_error = true; one_fault<BissConfig, BissDecoder>(c, emit, f, "error_flag", &PositionWordStats::error_flags); }
    SECTION("not ready") { f.not_ready = true; one_fault<BissConfig, BissDecoder>(c, emit, f, "not_ready", &PositionWordStats::not_ready); }
    SECTION("the warning bit nW is counted, the word stays valid") {
        f.set_warning = true;
        LogicSignals s;
        for (int i = 0; i < 5; ++i) emit_biss_frame(c, timing(), 1000 + static_cast<std::uint64_t>(i), i == 3 ? f : WordFault{}, s);
        BissDecoder d(c);
        const auto w = run(d, s);
        REQUIRE(w.size() == 5);
        for (std::size_t i = 0; i < 5; ++i) CHECK((w[i].valid && w[i].value == 1000 + i));
        CHECK(d.stats().warning_flags == 1);
        CHECK(d.stats().invalid_words == 0);
    }
}

TEST_CASE("BiSS-C: a slave that never acknowledges gives no_start, one per frame", "[dut][words]") {
    // MA clocks frames while SLO stays high: every frame is counted as no_start.
    BissConfig c;
    c.position_bits = 12;
    c.max_ack_bits = 4;
    LogicSignals s;
    for (int i = 0; i < 3; ++i) emit_ssi_frame([] { SsiConfig k; k.position_bits = 40; k.error_bits = 0; return k; }(), timing(),
                                               mask(40), {}, s);  // all ones: SLO high
    BissDecoder d(c);
    const auto w = run(d, s);
    REQUIRE(w.size() == 3);
    for (const auto& x : w) CHECK(x.error == "no_start");
    CHECK(d.stats().no_start == 3);
}

TEST_CASE("BiSS-C: an Ack of max_ack_bits clocks is read, one clock longer is no_start", "[dut][words]") {
    for (int max_ack : {1, 4, 32}) {
        BissConfig c;
        c.position_bits = 16;
        c.max_ack_bits = max_ack;
        for (int ack : {max_ack, max_ack + 1}) {
            CAPTURE(max_ack, ack);
            EmitterTiming tm = timing();
            tm.ack_bits = ack;
            LogicSignals s;
            emit_biss_frame(c, tm, 0xBEEF, {}, s);
            BissDecoder d(c);
            const auto w = run(d, s);
            REQUIRE(w.size() == 1);
            if (ack <= max_ack) CHECK((w[0].valid && w[0].value == 0xBEEF));
            else CHECK(w[0].error == "no_start");
        }
    }
}

TEST_CASE("SPI faults: each is counted and invalidates exactly its word", "[dut][words]") {
    SpiConfig c;
    c.mode = 3;
    c.word_bits = 16;
    c.position_bits = 12;
    c.position_shift = 2;
    c.error_bit = 0;
    c.error_active_high = false;
    auto emit = [](const SpiConfig& k, const EmitterTiming& tm, std::uint64_t v, const WordFault& f, LogicSignals& s) {
        return emit_spi_frame(k, tm, v, f, s);
    };
    WordFault f;
    SECTION("a dropped clock") { f.drop_clock = 15; one_fault<SpiConfig, SpiDecoder>(c, emit, f, "short_frame", &PositionWordStats::short_frames); }
    SECTION("an extra clock") { f.extra_clocks = 2; one_fault<SpiConfig, SpiDecoder>(c, emit, f, "long_frame", &PositionWordStats::long_frames); }
    SECTION("the error bit (active low)") { f.set_error = true; one_fault<SpiConfig, SpiDecoder>(c, emit, f, "error_flag", &PositionWordStats::error_flags); }
}

TEST_CASE("Blocks split at every sample give the same words (state carried across blocks)", "[dut][words]") {
    const EmitterTiming tm = timing();
    SsiConfig sc;
    sc.position_bits = 12;
    sc.error_bits = 1;
    BissConfig bc;
    bc.position_bits = 10;
    SpiConfig pc;
    pc.mode = 2;
    pc.word_bits = 10;
    LogicSignals ss, bs, ps;
    WordFault drop;
    drop.drop_clock = 3;
    for (int i = 0; i < 3; ++i) {
        emit_ssi_frame(sc, tm, 1000 + static_cast<std::uint64_t>(i), i == 1 ? drop : WordFault{}, ss);
        emit_biss_frame(bc, tm, 500 + static_cast<std::uint64_t>(i), i == 1 ? drop : WordFault{}, bs);
        emit_spi_frame(pc, tm, 700 + static_cast<std::uint64_t>(i), i == 1 ? drop : WordFault{}, ps);
    }
    auto check_all_splits = [](auto make, const LogicSignals& s) {
        auto d0 = make();
        const auto whole = run(d0, s);
        REQUIRE(whole.size() == 3);
        CHECK(!whole[1].valid);
        for (std::size_t cut = 0; cut <= s.t_s.size(); ++cut) {
            auto d = make();
            const auto w = run(d, s, {cut});
            CAPTURE(cut);
            same_words(whole, w);
            CHECK(d.stats().samples == s.t_s.size());
        }
        auto d1 = make();  // sample by sample
        std::vector<std::size_t> every;
        for (std::size_t i = 1; i < s.t_s.size(); ++i) every.push_back(i);
        same_words(whole, run(d1, s, every));
    };
    check_all_splits([&] { return SsiDecoder(sc); }, ss);
    check_all_splits([&] { return BissDecoder(bc); }, bs);
    check_all_splits([&] { return SpiDecoder(pc); }, ps);
}

TEST_CASE("Hostile logic input: constant lines, a free-running clock, noise, glitches", "[dut][words]") {
    const std::size_t n = 20000;
    LogicSignals s;
    for (std::size_t i = 0; i < n; ++i) s.t_s.push_back(static_cast<double>(i) * 1e-6);
    auto lines = [&](double clk, double data, double cs) {
        s.clk.assign(n, clk);
        s.data.assign(n, data);
        s.cs.assign(n, cs);
    };
    SsiConfig sc;
    sc.position_bits = 16;
    BissConfig bc;
    bc.position_bits = 16;
    SpiConfig pc;
    pc.word_bits = 16;
    SECTION("all ones and all zeros: no frame") {
        for (double v : {0.0, 1.0}) {
            lines(v, v, v);
            SsiDecoder a(sc);
            BissDecoder b(bc);
            SpiDecoder c(pc);
            CHECK(run(a, s).empty());
            CHECK(run(b, s).empty());
            CHECK(run(c, s).empty());
        }
    }
    SECTION("a clock that never stops, data low: one frame that never ends, closed by finish as invalid") {
        lines(0, 0, 0);
        for (std::size_t i = 0; i < n; ++i) s.clk[i] = (i / 2) % 2 == 0 ? 1 : 0;
        for (std::size_t i = 0; i < 40; ++i) s.clk[i] = 1;  // idle first, so a frame starts
        SsiDecoder a(sc);
        const auto wa = run(a, s);
        REQUIRE(wa.size() == 1);
        CHECK(wa[0].error == "not_ready");
        BissDecoder b(bc);
        const auto wb = run(b, s);
        REQUIRE(wb.size() == 1);
        CHECK(!wb[0].valid);
        s.data.assign(n, 1.0);
        SsiDecoder a2(sc);
        const auto wa2 = run(a2, s);
        REQUIRE(wa2.size() == 1);
        CHECK(wa2[0].error == "long_frame");
    }
    SECTION("SPI: CS held low with a clock, CS toggling without a clock") {
        lines(0, 1, 1);
        for (std::size_t i = 100; i < n; ++i) {
            s.cs[i] = 0;
            s.clk[i] = (i / 2) % 2;
        }
        SpiDecoder c(pc);
        const auto w = run(c, s);
        REQUIRE(w.size() == 1);  // cut by the end of the capture
        CHECK(w[0].error == "short_frame");
        lines(0, 1, 1);
        for (std::size_t i = 0; i < n; ++i) s.cs[i] = (i / 10) % 2;
        SpiDecoder c2(pc);
        const auto w2 = run(c2, s);
        CHECK(w2.size() == n / 20 - 1);  // every CS frame but the one the capture starts in: short (no bits)
        CHECK(c2.stats().short_frames == w2.size());
        CHECK(c2.stats().valid_words == 0);
    }
    SECTION("random noise on every line: bounded output, every word accounted for") {
        std::mt19937 rng(7);
        for (int trial = 0; trial < 5; ++trial) {
            lines(0, 0, 0);
            for (std::size_t i = 0; i < n; ++i) {  // bursts of noise between idle stretches, so frames start
                s.clk[i] = i % 500 < 30 ? 1 : rng() & 1;
                s.data[i] = rng() & 1;
                s.cs[i] = (rng() % 8) != 0;
            }
            SsiDecoder a(sc);
            BissDecoder b(bc);
            SpiDecoder c(pc);
            const auto wa = run(a, s), wb = run(b, s), wc = run(c, s);
            for (const PositionWordStats* st : {&a.stats(), &b.stats(), &c.stats()}) {
                CHECK(st->valid_words + st->invalid_words == st->frames);
                CHECK(st->frames <= n / 2);
                CHECK(st->invalid_words == st->not_ready + st->no_start + st->short_frames + st->long_frames + st->crc_errors +
                                               st->error_flags + st->out_of_range);
            }
            CHECK(wa.size() == a.stats().frames);
            CHECK(wb.size() == b.stats().frames);
            CHECK(wc.size() == c.stats().frames);
        }
    }
    SECTION("a one-sample glitch on the clock invalidates only its frame") {
        EmitterTiming tm = timing();
        tm.half_clock_samples = 4;
        LogicSignals g;
        std::size_t glitch_at = 0;
        for (int i = 0; i < 5; ++i) {  // in frame 2, the 2nd of the 4 low samples of clock pulse 10 (a data bit)
            if (i == 2) glitch_at = g.t_s.size() + static_cast<std::size_t>(tm.idle_samples) + 8 * 10 + 1;
            emit_biss_frame(bc, tm, 4000 + static_cast<std::uint64_t>(i), {}, g);
        }
        REQUIRE((g.clk[glitch_at - 1] == 0 && g.clk[glitch_at] == 0 && g.clk[glitch_at + 1] == 0));
        g.clk[glitch_at] = 1;  // an extra clock pulse one sample wide
        BissDecoder b(bc);
        const auto w = run(b, g);
        REQUIRE(w.size() == 5);
        for (std::size_t i = 0; i < 5; ++i) CHECK(w[i].valid == (i != 2));
        CHECK(b.stats().invalid_words == 1);
    }
}

TEST_CASE("Angle mapping: the cell centre, cycles per revolution, offset, unwrapped across the word's wrap", "[dut][words]") {
    // 10-bit word, 1000 counts per revolution, 4 electrical cycles per revolution, offset 0.3 rad:
    // theta = 0.3 + 2*pi*4*(turns + (v + 0.5)/1000).
    BissConfig c;
    c.position_bits = 10;
    c.angle.counts_per_rev = 1000;
    c.angle.cycles_per_rev = 4;
    c.angle.offset_rad = 0.3;
    const std::vector<std::uint64_t> vals = {0, 990, 999, 3, 8, 500, 2, 998, 1000, 1023, 997};
    const std::vector<int> turns = {0, -1, -1, 0, 0, 0, 0, -1, 0, 0, -1};  // 1000, 1023: out of range
    LogicSignals s;
    for (auto v : vals) emit_biss_frame(c, timing(), v, {}, s);
    BissDecoder d(c);
    const auto w = run(d, s);
    REQUIRE(w.size() == vals.size());
    for (std::size_t i = 0; i < vals.size(); ++i) {
        CAPTURE(i, vals[i]);
        if (vals[i] >= 1000) {
            CHECK(!w[i].valid);
            CHECK(w[i].error == "out_of_range");
            continue;
        }
        REQUIRE(w[i].valid);
        CHECK(w[i].theta_rad == Approx(0.3 + kTwoPiT * 4 * (turns[i] + (static_cast<double>(vals[i]) + 0.5) / 1000)).margin(1e-12));
    }
    CHECK(d.stats().out_of_range == 2);
    CHECK(d.stats().wraps == 3);  // 0->990 back, 999->3 forward, 2->998 back; 500->2 is a step, not a wrap
    CHECK(d.to_json().value("angle", nlohmann::json{}).value("step_rad", 0.0) == Approx(kTwoPiT * 4 / 1000));
    // the whole 64-bit range: 2^64 counts per revolution by default
    BissConfig c64;
    c64.position_bits = 64;
    LogicSignals s64;
    for (std::uint64_t v : {~std::uint64_t{0}, std::uint64_t{5}, std::uint64_t{1} << 63})
        emit_biss_frame(c64, timing(), v, {}, s64);
    BissDecoder d64(c64);
    const auto w64 = run(d64, s64);
    REQUIRE(w64.size() == 3);
    CHECK(w64[0].theta_rad == Approx(kTwoPiT).epsilon(1e-15));
    CHECK(w64[1].theta_rad == Approx(kTwoPiT).epsilon(1e-15));  // wrapped forward: one turn + 5.5 counts
    CHECK(w64[2].theta_rad == Approx(kTwoPiT * 1.5).epsilon(1e-15));
    CHECK_THROWS_AS(BissDecoder([] { BissConfig b; b.position_bits = 10; b.angle.counts_per_rev = 1025; return b; }()), std::invalid_argument);
    CHECK_THROWS_AS(BissDecoder([] { BissConfig b; b.position_bits = 0; return b; }()), std::invalid_argument);
    CHECK_THROWS_AS(BissDecoder([] { BissConfig b; b.position_bits = 8; b.angle.cycles_per_rev = 0; return b; }()), std::invalid_argument);
}

TEST_CASE("Position stream: lines parse to words, malformed lines are counted", "[dut][words]") {
    StreamConfig c;
    c.position_bits = 12;
    c.angle.cycles_per_rev = 2;
    const std::string text =
        "# DUT position stream\n"
        "0.001 0\n"
        "0.002\t4095\r\n"
        "\n"
        "  0.003 , 17  \n"
        "3e-3 18 E\n"        // flagged by the DUT
        "0.0025 19\n"        // time reversal
        "0.004 4096\n"       // out of range
        "0.005 -1\n"         // malformed: negative
        "0.006 12x\n"        // malformed
        "0.007\n"            // malformed: one field
        "0.008 1 2\n"        // malformed: third field not E
        "nan 5\n"            // malformed
        "inf 5\n"            // malformed
        "0x10 5\n"           // malformed: hex
        "0.009 99999999999999999999999\n"  // malformed: overflow
        "0.010,,5\n"         // malformed: empty field
        "0.011 20 E extra\n" // malformed: four fields
        "0.012 21";          // no LF: finish() reads it
    PositionStreamParser ref(c);
    std::vector<PositionWord> whole;
    ref.feed(text.data(), text.size(), whole);
    ref.finish(whole);
    REQUIRE(whole.size() == 7);
    const double step = kTwoPiT * 2 / 4096;
    CHECK(whole[0].t_s == 0.001);
    CHECK(whole[0].theta_rad == Approx(0.5 * step));
    CHECK(whole[1].theta_rad == Approx(-0.5 * step));  // 0 -> 4095 is one count back across the wrap
    CHECK(whole[2].value == 17);
    CHECK(whole[2].theta_rad == Approx(17.5 * step));
    CHECK(whole[3].error == "error_flag");
    CHECK(whole[4].error == "time_reversal");
    CHECK(whole[5].error == "out_of_range");
    CHECK((whole[6].valid && whole[6].value == 21 && whole[6].t_s == 0.012));
    const PositionWordStats& st = ref.stats();
    CHECK(st.malformed_lines == 10);
    CHECK(st.error_flags == 1);
    CHECK(st.time_reversals == 1);
    CHECK(st.out_of_range == 1);
    CHECK(st.valid_words == 4);
    CHECK(st.invalid_words == 3);
    // any split of the bytes gives the same words
    for (std::size_t cut = 0; cut <= text.size(); ++cut) {
        PositionStreamParser p(c);
        std::vector<PositionWord> w;
        p.feed(text.data(), cut, w);
        p.feed(text.data() + cut, text.size() - cut, w);
        p.finish(w);
        CAPTURE(cut);
        same_words(whole, w);
        CHECK(p.stats().malformed_lines == 10);
    }
}

TEST_CASE("Position stream: sample-index time, overlong lines bounded, binary garbage", "[dut][words]") {
    StreamConfig c;
    c.time_unit = "sample";
    c.sample_rate_hz = 1000;
    c.max_line_bytes = 32;
    PositionStreamParser p(c);
    std::vector<PositionWord> w;
    std::string text = "10 5\n" + std::string(100000, '7') + "\n20 6\n" + std::string(40, 'x');
    p.feed(text.data(), text.size(), w);
    p.finish(w);
    REQUIRE(w.size() == 2);
    CHECK(w[0].t_s == 0.01);
    CHECK(w[1].t_s == 0.02);
    CHECK(p.stats().malformed_lines == 2);  // the overlong line and the unterminated overlong tail
    // random bytes: no crash, every line either a word or counted as malformed
    std::mt19937 rng(3);
    StreamConfig g;
    PositionStreamParser q(g);
    std::vector<PositionWord> out;
    std::string junk(200000, '\0');
    for (char& ch : junk) ch = static_cast<char>(rng() % 16 == 0 ? '\n' : rng() % 256);
    q.feed(junk.data(), junk.size(), out);
    q.finish(out);
    CHECK(out.size() == q.stats().frames);
    CHECK(q.stats().malformed_lines > 0);
    CHECK_THROWS_AS(PositionStreamParser([] { StreamConfig b; b.time_unit = "sample"; return b; }()), std::invalid_argument);
    CHECK_THROWS_AS(PositionStreamParser([] { StreamConfig b; b.time_unit = "ms"; return b; }()), std::invalid_argument);
    const auto j = p.to_json();
    CHECK(j.value("lines", 0) == 4);
    CHECK(j.value("protocol", "") == "stream");
}

TEST_CASE("Decoder reports name their settings and counts", "[dut][words]") {
    SsiConfig c;
    c.position_bits = 13;
    c.code = WordCode::gray;
    SsiDecoder d(c);
    const auto j = d.to_json();
    for (const char* k : {"protocol", "position_bits", "code", "timeout_s", "angle", "frames", "valid_words", "invalid_words", "short_frames",
                          "long_frames", "not_ready", "error_flags", "crc_errors", "min_frame_interval_s"})
        CHECK(j.contains(k));
    CHECK(j.value("code", "") == "gray");
    CHECK(j.value("protocol", "") == "ssi");
}

TEST_CASE("Readout settings round-trip through JSON, unknown keys and wrong types are refused by name", "[dut][words]") {
    SsiConfig ssi;
    ssi.position_bits = 25;
    ssi.code = WordCode::gray;
    ssi.error_bits = 1;
    ssi.error_active_high = false;
    ssi.timeout_s = 30e-6;
    ssi.angle = {1u << 25, 2048, 0.25};
    const SsiConfig ssi2 = nlohmann::json(ssi).get<SsiConfig>();
    CHECK(nlohmann::json(ssi2) == nlohmann::json(ssi));
    CHECK((ssi2.position_bits == 25 && ssi2.code == WordCode::gray && ssi2.error_bits == 1 && !ssi2.error_active_high &&
           ssi2.timeout_s == 30e-6 && ssi2.angle.counts_per_rev == (1u << 25) && ssi2.angle.cycles_per_rev == 2048 && ssi2.angle.offset_rad == 0.25));
    BissConfig biss;
    biss.position_bits = 64;
    biss.max_ack_bits = 5;
    biss.angle.counts_per_rev = ~std::uint64_t{0};
    const BissConfig biss2 = nlohmann::json(biss).get<BissConfig>();
    CHECK((biss2.position_bits == 64 && biss2.max_ack_bits == 5 && biss2.angle.counts_per_rev == ~std::uint64_t{0}));
    SpiConfig spi;
    spi.mode = 3;
    spi.word_bits = 16;
    spi.msb_first = false;
    spi.position_bits = 14;
    spi.position_shift = 1;
    spi.error_bit = 15;
    const SpiConfig spi2 = nlohmann::json(spi).get<SpiConfig>();
    CHECK(nlohmann::json(spi2) == nlohmann::json(spi));
    CHECK((spi2.mode == 3 && !spi2.msb_first && spi2.position_shift == 1 && spi2.error_bit == 15));
    StreamConfig st;
    st.time_unit = "sample";
    st.sample_rate_hz = 1e5;
    st.max_line_bytes = 80;
    const StreamConfig st2 = nlohmann::json(st).get<StreamConfig>();
    CHECK((st2.time_unit == "sample" && st2.sample_rate_hz == 1e5 && st2.max_line_bytes == 80));
    // a missing key keeps its default
    const SpiConfig d = nlohmann::json{{"word_bits", 12}}.get<SpiConfig>();
    CHECK((d.word_bits == 12 && d.mode == 0 && d.msb_first && d.error_bit == -1));
    auto refused = [](const nlohmann::json& j, const std::string& words) {
        try {
            (void)j.get<SpiConfig>();
        } catch (const std::invalid_argument& e) {
            CHECK_THAT(e.what(), Catch::Contains(words));
            return;
        }
        FAIL("accepted " << j.dump());
    };
    refused({{"word_bits", 12}, {"wordbits", 12}}, "unknown setting \"wordbits\"");
    refused({{"word_bits", "12"}}, "word_bits: not an integer");
    refused({{"word_bits", 12.5}}, "word_bits: not an integer");
    refused({{"mode", 4294967296LL}}, "mode: out of range");
    refused({{"msb_first", 1}}, "msb_first: not a boolean");
    refused({{"code", "bcd"}}, "code must be");
    refused({{"offset_rad", "0"}}, "offset_rad: not a number");
    refused({{"counts_per_rev", -1}}, "counts_per_rev: out of range");
    refused(nlohmann::json::array(), "a JSON object");
    CHECK_THROWS_AS(nlohmann::json({{"time_unit", 3}}).get<StreamConfig>(), std::invalid_argument);
}

}  // namespace test_position_words_cpp
