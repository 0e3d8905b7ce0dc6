// Fuzz target: what a DUT (or anything on its wires or its port) sends (docs/dut-readouts.md).
// The first byte picks the reader: the line-oriented position stream (the rest as bytes,
// handed over in chunks whose sizes come from the input), or SSI, BiSS-C or SPI over logic
// samples (each further byte one sample: bit 0 clock, bit 1 data, bit 2 CS; settings from the
// second byte). Every reader must account for every word (valid + invalid = frames), never
// give a valid word a non-finite angle or an invalid one a finite angle, and never crash,
// hang or allocate without bound.
#include "drivers/position_words.hpp"

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <vector>

namespace {
using namespace fringe;

void check(const std::vector<PositionWord>& words, const PositionWordStats& st) {
    if (st.valid_words + st.invalid_words != st.frames) std::abort();
    if (words.size() != st.frames) std::abort();
    for (const auto& w : words) {
        if (w.valid != std::isfinite(w.theta_rad)) std::abort();
        if (!w.valid && w.error.empty()) std::abort();
    }
}

template <class Decoder, class Feed>
void logic(Decoder& d, const std::uint8_t* data, std::size_t n, Feed feed) {
    std::vector<double> t, clk, dat, cs;
    for (std::size_t i = 0; i < n; ++i) {
        t.push_back(static_cast<double>(i) * 1e-6);
        clk.push_back(data[i] & 1);
        dat.push_back((data[i] >> 1) & 1);
        cs.push_back((data[i] >> 2) & 1);
    }
    std::vector<PositionWord> words;
    // Two blocks split where the input says: the decoders carry their state across.
    const std::size_t cut = n ? data[0] % (n + 1) : 0;
    feed(d, 0, cut, t, clk, dat, cs, words);
    feed(d, cut, n - cut, t, clk, dat, cs, words);
    d.finish(words);
    check(words, d.stats());
    (void)d.to_json();
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    if (size < 2) return 0;
    const int kind = data[0] % 4;
    const int s = data[1];
    data += 2;
    size -= 2;
    try {
        if (kind == 0) {
            StreamConfig c;
            c.max_line_bytes = 8 + static_cast<std::size_t>(s % 64);
            if (s & 0x40) {
                c.time_unit = "sample";
                c.sample_rate_hz = 1e3;
            }
            c.angle.counts_per_rev = s & 0x80 ? 1000 : 0;
            PositionStreamParser p(c);
            std::vector<PositionWord> words;
            std::size_t pos = 0;
            while (pos < size) {
                const std::size_t k = std::min<std::size_t>(size - pos, 1 + data[pos] % 17);
                p.feed(reinterpret_cast<const char*>(data + pos), k, words);
                pos += k;
            }
            p.finish(words);
            check(words, p.stats());
            (void)p.to_json();
        } else if (kind == 1) {
            SsiConfig c;
            c.position_bits = 1 + s % 64;
            c.error_bits = (s >> 6) % 3;
            c.code = s & 1 ? WordCode::gray : WordCode::binary;
            c.timeout_s = 5e-6;
            SsiDecoder d(c);
            logic(d, data, size, [](SsiDecoder& x, std::size_t a, std::size_t n, auto& t, auto& clk, auto& dat, auto&, auto& w) {
                x.process(n, t.data() + a, clk.data() + a, dat.data() + a, w);
            });
        } else if (kind == 2) {
            BissConfig c;
            c.position_bits = 1 + s % 64;
            c.max_ack_bits = 1 + (s >> 6);
            c.timeout_s = 5e-6;
            BissDecoder d(c);
            logic(d, data, size, [](BissDecoder& x, std::size_t a, std::size_t n, auto& t, auto& clk, auto& dat, auto&, auto& w) {
                x.process(n, t.data() + a, clk.data() + a, dat.data() + a, w);
            });
        } else {
            SpiConfig c;
            c.mode = s % 4;
            c.word_bits = 1 + (s >> 2) % 64;
            c.msb_first = s & 0x80;
            c.error_bit = c.word_bits > 1 && (s & 0x40) ? 0 : -1;
            c.position_shift = c.error_bit == 0 ? 1 : 0;
            SpiDecoder d(c);
            logic(d, data, size, [](SpiDecoder& x, std::size_t a, std::size_t n, auto& t, auto& clk, auto& dat, auto& cs, auto& w) {
                x.process(n, t.data() + a, cs.data() + a, clk.data() + a, dat.data() + a, w);
            });
        }
    } catch (const std::invalid_argument&) {
        // a combination of settings a decoder refuses: not a crash
    }
    return 0;
}
