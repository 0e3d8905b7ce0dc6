// Fuzz target: what an instrument (or anything pretending to be one on port 5025) sends back.
// The bytes go through the real SCPI session reader (drivers/scpi.hpp: lines, IEEE 488.2
// definite and indefinite blocks, SYST:ERR? entries) over a link that hands them out in
// chunks, and through the pure block and USBTMC header parsers. Errors must be DeviceErrors
// or runtime_errors with a message, never crashes, hangs or huge allocations.
#include "drivers/scpi.hpp"

#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string_view>

namespace {
using namespace fringe::dev;

// Serves the input in chunks of 1..64 bytes (sizes from the input itself); then "closed".
class FuzzLink final : public scpi::Link {
public:
    explicit FuzzLink(std::string_view d) : d_(d) {}
    void write_message(std::string_view, double) override {}
    std::size_t read_some(char* buf, std::size_t n, double, bool* end) override {
        *end = false;
        if (pos_ >= d_.size()) throw std::runtime_error("connection closed by the instrument");
        const std::size_t chunk = 1 + static_cast<unsigned char>(d_[pos_]) % 64;
        const std::size_t k = std::min({n, chunk, d_.size() - pos_});
        std::copy(d_.data() + pos_, d_.data() + pos_ + k, buf);
        pos_ += k;
        *end = framed_ && pos_ == d_.size();
        return k;
    }
    std::string describe() const override { return "fuzz"; }
    bool message_framed() const override { return framed_; }
    bool framed_ = false;

private:
    std::string_view d_;
    std::size_t pos_ = 0;
};
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string_view in(reinterpret_cast<const char*>(data), size);
    constexpr std::size_t kMax = 1 << 16;
    try {
        const std::string b = scpi::decode_block(in, kMax);
        if (b.size() > kMax) std::abort();
        if (scpi::decode_block(scpi::encode_block(b), kMax) != b) std::abort();  // round trip
    } catch (const std::runtime_error&) {
    }
    try {
        (void)scpi::parse_error_entry(in);
    } catch (const std::runtime_error&) {
    }
    if (size >= 12) {
        try {
            (void)scpi::usbtmc::decode_in_header(data, size, data[1], 1 << 20);
        } catch (const std::runtime_error&) {
        }
    }
    // The session: the first byte picks line/block reads and the framing.
    for (int framed = 0; framed < 2; ++framed) {
        auto link = std::make_unique<FuzzLink>(in.substr(size ? 1 : 0));
        link->framed_ = framed != 0;
        scpi::Session s(std::move(link), "scpi+tcp://fuzz", 1.0, kMax);
        const unsigned pattern = size ? static_cast<unsigned char>(data[0]) : 0;
        try {
            for (int k = 0; k < 16; ++k) {
                if (pattern >> (k % 8) & 1) {
                    if (s.read_block("FUZZ:DATA?").size() > kMax) std::abort();
                } else {
                    if (s.read_line("FUZZ?").size() > kMax + 65536) std::abort();
                }
            }
        } catch (const DeviceError&) {
        }
    }
    return 0;
}
