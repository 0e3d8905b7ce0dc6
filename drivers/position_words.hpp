// Position-word readouts of a DUT (docs/dut-readouts.md): decoders for the serial position
// protocols of absolute encoders and interpolator ICs (SSI, BiSS-C, SPI) from logic channels
// sampled at a fixed rate, a parser for a line-oriented position stream (serial or TCP text),
// and emitters that turn a position sequence into the wire signals (for tests and an emulated
// DUT), with fault injection.
//
// Conventions (docs/dut-readouts.md):
//  - Logic inputs are arrays of samples, nonzero = 1, with the time t_s of each sample; they
//    arrive block by block and every decoder carries its state across blocks, so any split of
//    a capture into blocks gives the same words.
//  - A word is time-stamped at its latch instant: the wire event at which the encoder samples
//    its position (SSI: the first falling clock edge of the frame; BiSS-C: the first rising
//    edge of MA; SPI: the CS assertion), at the first sample that shows it.
//  - An edge is seen at the first sample after it; data is read at that sample (as sigrok's
//    spi decoder does).
//  - A word on the wire is never guessed: a frame with the wrong number of bits, cut by a
//    timeout, with a bad CRC, with its error bit set, or out of the configured range is
//    counted in the stats and yields an invalid word (valid = false, theta_rad = NaN).
//  - Angle: word value v (0 <= v < M, M = counts_per_rev) is the cell [v, v+1) of M per
//    revolution; theta_rad = offset_rad + 2*pi*cycles_per_rev*(turns + (v + 0.5)/M), the cell's
//    centre (as the ABZ readout), turns counted by unwrapping consecutive valid words (a step
//    of more than M/2 is taken as a wrap): the angle is continuous across the word's wrap.
#pragma once

#include <nlohmann/json.hpp>

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace fringe {

enum class WordCode { binary, gray };

// Word value -> electrical angle, shared by every readout.
struct WordAngleMap {
    std::uint64_t counts_per_rev = 0;  // M: word values per revolution; 0 = 2^position_bits
    int cycles_per_rev = 1;            // electrical cycles per revolution of the word (>= 1)
    double offset_rad = 0;             // electrical angle of value 0's lower edge
};

// One decoded position word.
struct PositionWord {
    double t_s = 0;            // latch instant
    std::uint64_t value = 0;   // position field as read, after Gray decoding (0 when the frame is unreadable)
    bool valid = false;
    double theta_rad = 0;      // NaN when invalid
    std::string error;         // why invalid ("" when valid): "crc", "short_frame", ...
};

// What a readout counts. Every invalid word is counted once in invalid_words and once under
// exactly one cause (the first that applies, in the order of the fields below).
struct PositionWordStats {
    std::uint64_t samples = 0;
    std::uint64_t frames = 0;          // frames seen (each gives one word, valid or not)
    std::uint64_t valid_words = 0, invalid_words = 0;
    std::uint64_t not_ready = 0;       // SSI/BiSS: data line low at the frame's start (slave busy)
    std::uint64_t no_start = 0;        // BiSS: no ack/start bit before the frame ended
    std::uint64_t short_frames = 0;    // fewer bits than the frame needs (timeout or CS mid-frame)
    std::uint64_t long_frames = 0;     // more bits than the frame holds
    std::uint64_t crc_errors = 0;      // BiSS: CRC6 mismatch
    std::uint64_t error_flags = 0;     // the frame's error bit set (SSI/SPI error bit, BiSS nE low)
    std::uint64_t out_of_range = 0;    // value >= counts_per_rev
    std::uint64_t malformed_lines = 0; // stream: lines that do not parse
    std::uint64_t time_reversals = 0;  // stream: a time before the previous line's
    std::uint64_t warning_flags = 0;   // BiSS nW low (counted; the word stays valid)
    std::uint64_t wraps = 0;           // unwrapped turns (either direction)
    double min_frame_interval_s = 0;   // shortest time between two latches (0: fewer than two frames)
};

// The angle of successive words: range check and unwrapping (shared by every readout).
class WordAngle {
public:
    WordAngle(WordAngleMap m, int position_bits);  // throws std::invalid_argument
    // Checks range, unwraps, fills w.valid/theta_rad/error and counts into st.
    void finish_word(PositionWord& w, PositionWordStats& st);
    std::uint64_t counts_per_rev() const { return m_; }  // 0 = 2^64
    double step_rad() const { return step_; }
    nlohmann::json to_json() const;

private:
    WordAngleMap map_;
    std::uint64_t m_;  // modulus; 0 stands for 2^64
    double step_;
    bool have_prev_ = false;
    std::uint64_t prev_ = 0;
    long long turns_ = 0;
    bool have_latch_ = false, have_interval_ = false;
    double last_latch_t_ = 0;
};

std::uint64_t gray_to_binary(std::uint64_t g);
std::uint64_t binary_to_gray(std::uint64_t b);
// BiSS CRC6, polynomial x^6 + x + 1 (0x43), start value 0, over n bits MSB first (bits[0]
// first); the value before inversion (BiSS sends it inverted).
unsigned biss_crc6(const std::uint8_t* bits, std::size_t n);

// ---- SSI ----
// Frame (clock idles high, data idles high): the first falling clock edge latches the position
// (data must be high there: ready); each rising edge shifts out the next bit, MSB first, and
// the master reads it at the next falling edge: falling edges 2 .. 1+B carry the B =
// position_bits + error_bits bits. After the last bit the encoder holds data low for its
// monoflop time; the frame ends when the clock stays high for timeout_s.
struct SsiConfig {
    int position_bits = 0;        // 1..64
    WordCode code = WordCode::binary;
    int error_bits = 0;           // status bits after the position (0..8), not Gray coded
    bool error_active_high = true;  // a status bit at this level flags an error
    double timeout_s = 20e-6;     // monoflop: clock high this long ends a frame
    WordAngleMap angle;
};

// ---- BiSS-C (point-to-point, sensor data only) ----
// Frame (MA idles high, SLO idles high): the first rising edge of MA after it leaves idle
// latches the position; SLO then answers, read at falling edges of MA: high while the slave
// has not yet acknowledged, low for the Ack (processing time, >= 1 bit), then Start (1), CDS
// (0), position_bits data bits MSB first, nE and nW (active low), and CRC6 (x^6+x+1, start
// 0, over data + nE + nW, MSB first) sent inverted. The frame ends when MA stays high for
// timeout_s.
struct BissConfig {
    int position_bits = 0;        // 1..64
    WordCode code = WordCode::binary;
    int max_ack_bits = 32;        // clock periods before the start bit, at most
    double timeout_s = 20e-6;
    WordAngleMap angle;
};

// ---- SPI ----
// One word per CS frame (CS active low). Mode = 2*CPOL + CPHA: data is read on the rising
// clock edge in modes 0 and 3, on the falling edge in modes 1 and 2. word_bits bits, MSB or
// LSB first; the position is the field of position_bits bits at position_shift (bit 0 = the
// word's least significant bit); error_bit (-1: none) flags an error at error_active_high.
struct SpiConfig {
    int mode = 0;                 // 0..3
    int word_bits = 0;            // 1..64
    bool msb_first = true;
    int position_bits = 0;        // 1..word_bits - position_shift (0: word_bits - position_shift)
    int position_shift = 0;
    int error_bit = -1;
    bool error_active_high = true;
    WordCode code = WordCode::binary;
    WordAngleMap angle;
};

class SsiDecoder {
public:
    explicit SsiDecoder(SsiConfig c);  // throws std::invalid_argument
    // n samples of the clock and data lines; words completed in this block are appended.
    void process(std::size_t n, const double* t_s, const double* clk, const double* data, std::vector<PositionWord>& out);
    // End of the capture: a frame still open is closed as if its timeout had run out.
    void finish(std::vector<PositionWord>& out);
    const PositionWordStats& stats() const { return st_; }
    nlohmann::json to_json() const;

private:
    void close_frame(std::vector<PositionWord>& out);
    SsiConfig cfg_;
    WordAngle angle_;
    PositionWordStats st_;
    bool started_ = false, prev_clk_ = true, in_frame_ = false, ready_ = true, idle_ok_ = false;
    double last_rise_t_ = 0, latch_t_ = 0;
    int falls_ = 0;                // falling edges in the frame
    std::uint64_t pos_ = 0, status_ = 0;
};

class BissDecoder {
public:
    explicit BissDecoder(BissConfig c);  // throws std::invalid_argument
    void process(std::size_t n, const double* t_s, const double* ma, const double* slo, std::vector<PositionWord>& out);
    void finish(std::vector<PositionWord>& out);
    const PositionWordStats& stats() const { return st_; }
    nlohmann::json to_json() const;

private:
    enum class Phase { request, ack, data, overrun };
    void close_frame(std::vector<PositionWord>& out);
    BissConfig cfg_;
    WordAngle angle_;
    PositionWordStats st_;
    bool started_ = false, prev_ma_ = true, in_frame_ = false, ready_ = true, latched_ = false, idle_ok_ = false;
    double last_rise_t_ = 0, latch_t_ = 0;
    Phase phase_ = Phase::request;
    int waited_ = 0;               // falling edges before the start bit
    int nbits_ = 0;                // bits after the start bit (CDS first)
    std::vector<std::uint8_t> bits_;  // CDS, data, nE, nW, CRC (at most 1 + 64 + 2 + 6)
};

class SpiDecoder {
public:
    explicit SpiDecoder(SpiConfig c);  // throws std::invalid_argument
    void process(std::size_t n, const double* t_s, const double* cs, const double* sclk, const double* data,
                 std::vector<PositionWord>& out);
    void finish(std::vector<PositionWord>& out);  // a frame still open (CS low) is short
    const PositionWordStats& stats() const { return st_; }
    nlohmann::json to_json() const;

private:
    void close_frame(std::vector<PositionWord>& out);
    SpiConfig cfg_;
    int position_bits_;
    WordAngle angle_;
    PositionWordStats st_;
    bool started_ = false, prev_cs_ = true, prev_clk_ = false, in_frame_ = false;
    double latch_t_ = 0;
    int nbits_ = 0;
    std::uint64_t word_ = 0;
};

// ---- Line-oriented position stream ----
// One position per line: "<time> <count>" (fields separated by spaces, tabs or one comma),
// optionally a third field "E" (the DUT flags the position as erroneous). <time> is seconds
// (a decimal or exponent number) or, with time_unit "sample", a sample index (an integer,
// t_s = index / sample_rate_hz); <count> is a decimal integer in [0, counts_per_rev). Lines end
// with LF (a CR before it is dropped); empty lines and lines starting with '#' are skipped.
// A line longer than max_line_bytes, or that does not parse, is a malformed line: counted, no
// word. A time before the previous word's is a time reversal: counted, invalid word.
struct StreamConfig {
    std::string time_unit = "s";    // "s" or "sample"
    double sample_rate_hz = 0;      // for time_unit "sample" (> 0)
    int position_bits = 32;         // for counts_per_rev = 0 (1..64)
    std::size_t max_line_bytes = 256;
    WordAngleMap angle;
};

class PositionStreamParser {
public:
    explicit PositionStreamParser(StreamConfig c);  // throws std::invalid_argument
    // Bytes as they arrive (any split); complete lines become words appended to out.
    void feed(const char* bytes, std::size_t n, std::vector<PositionWord>& out);
    void finish(std::vector<PositionWord>& out);  // a last line without LF
    const PositionWordStats& stats() const { return st_; }
    nlohmann::json to_json() const;

private:
    void line(std::vector<PositionWord>& out);
    StreamConfig cfg_;
    WordAngle angle_;
    PositionWordStats st_;
    std::string buf_;
    bool overlong_ = false;
    bool have_t_ = false;
    double last_t_ = 0;
};

// ---- Emitters: positions -> wire signals (tests, emulated DUTs) ----
struct LogicSignals {
    std::vector<double> t_s, clk, data, cs;  // cs empty for SSI and BiSS
};

struct EmitterTiming {
    double sample_rate_hz = 1e6;
    int half_clock_samples = 2;   // samples per half clock period (>= 1)
    int idle_samples = 40;        // lines at rest before each frame (the timeout after it is added by the emitter)
    int ack_bits = 1;             // BiSS: Ack length in clock periods (>= 1)
};

// Faults injected into one frame.
struct WordFault {
    int flip_bit = -1;            // invert this wire bit (0 = the first bit the master reads after the latch)
    int drop_clock = -1;          // leave out this clock pulse (0 = the first)
    int extra_clocks = 0;         // clock pulses after the frame's last
    bool set_error = false;       // SSI/SPI: the error bit at its active level; BiSS: nE low
    bool set_warning = false;     // BiSS: nW low
    bool not_ready = false;       // SSI/BiSS: data low at the frame's start
};

// Each call appends idle_samples of idle lines and one frame carrying value (already in the
// word's range; Gray-coded here when the config says so); returns the frame's latch time.
double emit_ssi_frame(const SsiConfig& c, const EmitterTiming& tm, std::uint64_t value, const WordFault& f, LogicSignals& out);
double emit_biss_frame(const BissConfig& c, const EmitterTiming& tm, std::uint64_t value, const WordFault& f, LogicSignals& out);
double emit_spi_frame(const SpiConfig& c, const EmitterTiming& tm, std::uint64_t value, const WordFault& f, LogicSignals& out);
// Appends samples that repeat the last sample's levels (all lines high when out is empty).
void emit_idle(const EmitterTiming& tm, int samples, LogicSignals& out);

nlohmann::json to_json(const PositionWordStats& s);

// Settings as JSON, in one place (docs/dut-readouts.md tables; the angle keys counts_per_rev,
// cycles_per_rev and offset_rad sit beside the protocol's). from_json starts from the defaults,
// and throws std::invalid_argument naming the key for an unknown key or a value of the wrong
// type or out of its range; the decoders' constructors check the combination.
void to_json(nlohmann::json& j, const SsiConfig& c);
void from_json(const nlohmann::json& j, SsiConfig& c);
void to_json(nlohmann::json& j, const BissConfig& c);
void from_json(const nlohmann::json& j, BissConfig& c);
void to_json(nlohmann::json& j, const SpiConfig& c);
void from_json(const nlohmann::json& j, SpiConfig& c);
void to_json(nlohmann::json& j, const StreamConfig& c);
void from_json(const nlohmann::json& j, StreamConfig& c);

}  // namespace fringe
