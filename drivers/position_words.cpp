#include "position_words.hpp"
#include "signal_gen/base/constants.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <stdexcept>
#include <type_traits>

namespace fringe {

namespace {

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();

std::uint64_t low_mask(int bits) { return bits >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << bits) - 1; }

const char* code_name(WordCode c) { return c == WordCode::gray ? "gray" : "binary"; }

void check_bits(const char* who, const char* what, int bits) {
    if (bits < 1 || bits > 64)
        throw std::invalid_argument(std::string(who) + ": " + what + " must be 1..64, got " + std::to_string(bits));
}

void check_timeout(const char* who, double timeout_s) {
    if (!(timeout_s > 0) || !std::isfinite(timeout_s))
        throw std::invalid_argument(std::string(who) + ": timeout_s must be a positive number of seconds");
}

// Counts an invalid word under its cause.
void count_invalid(PositionWord& w, const char* cause, std::uint64_t& counter, PositionWordStats& st) {
    w.valid = false;
    w.theta_rad = kNan;
    w.error = cause;
    ++counter;
    ++st.invalid_words;
}

nlohmann::json angle_json(const WordAngleMap& m) {
    return {{"counts_per_rev", m.counts_per_rev}, {"cycles_per_rev", m.cycles_per_rev}, {"offset_rad", m.offset_rad}};
}

}  // namespace

std::uint64_t gray_to_binary(std::uint64_t g) {
    for (int s = 1; s < 64; s <<= 1) g ^= g >> s;
    return g;
}

std::uint64_t binary_to_gray(std::uint64_t b) { return b ^ (b >> 1); }

unsigned biss_crc6(const std::uint8_t* bits, std::size_t n) {
    // Long division by x^6 + x + 1, MSB first: the register holds the remainder; a bit that
    // shifts out of x^5 folds back as x + 1 (0x03).
    unsigned r = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const unsigned top = ((r >> 5) & 1u) ^ (bits[i] ? 1u : 0u);
        r = (r << 1) & 0x3Fu;
        if (top) r ^= 0x03u;
    }
    return r;
}

// ---- WordAngle ----

WordAngle::WordAngle(WordAngleMap m, int position_bits) : map_(m) {
    check_bits("position word", "position_bits", position_bits);
    if (m.cycles_per_rev < 1) throw std::invalid_argument("position word: cycles_per_rev must be at least 1");
    if (!std::isfinite(m.offset_rad)) throw std::invalid_argument("position word: offset_rad must be finite");
    if (m.counts_per_rev != 0 && position_bits < 64 && m.counts_per_rev > (std::uint64_t{1} << position_bits))
        throw std::invalid_argument("position word: counts_per_rev " + std::to_string(m.counts_per_rev) + " does not fit in " +
                                    std::to_string(position_bits) + " bits");
    if (m.counts_per_rev != 0) m_ = m.counts_per_rev;
    else m_ = position_bits >= 64 ? 0 : (std::uint64_t{1} << position_bits);
    const long double M = m_ == 0 ? std::ldexp(1.0L, 64) : static_cast<long double>(m_);
    step_ = static_cast<double>(static_cast<long double>(kTwoPi) * m.cycles_per_rev / M);
}

void WordAngle::finish_word(PositionWord& w, PositionWordStats& st) {
    ++st.frames;
    if (have_latch_ && w.t_s >= last_latch_t_) {
        const double dt = w.t_s - last_latch_t_;
        if (!have_interval_ || dt < st.min_frame_interval_s) st.min_frame_interval_s = dt;
        have_interval_ = true;
    }
    if (!have_latch_ || w.t_s >= last_latch_t_) last_latch_t_ = w.t_s;
    have_latch_ = true;
    if (!w.error.empty()) return;  // already counted by the protocol
    if (m_ != 0 && w.value >= m_) {
        count_invalid(w, "out_of_range", st.out_of_range, st);
        return;
    }
    const std::uint64_t v = w.value;
    if (have_prev_) {
        const std::uint64_t fwd = v >= prev_ ? v - prev_ : m_ - (prev_ - v);  // (v - prev) mod M
        const std::uint64_t back = m_ - fwd;                                   // (prev - v) mod M
        if (fwd <= back) {
            if (v < prev_) { ++turns_; ++st.wraps; }
        } else if (v > prev_) {
            --turns_;
            ++st.wraps;
        }
    }
    have_prev_ = true;
    prev_ = v;
    const long double M = m_ == 0 ? std::ldexp(1.0L, 64) : static_cast<long double>(m_);
    const long double rev = static_cast<long double>(turns_) + (static_cast<long double>(v) + 0.5L) / M;
    w.theta_rad = map_.offset_rad + static_cast<double>(static_cast<long double>(kTwoPi) * map_.cycles_per_rev * rev);
    w.valid = true;
    ++st.valid_words;
}

nlohmann::json WordAngle::to_json() const {
    nlohmann::json j = angle_json(map_);
    j["modulus"] = m_ == 0 ? nlohmann::json("2^64") : nlohmann::json(m_);
    j["step_rad"] = step_;
    j["turns"] = turns_;
    return j;
}

nlohmann::json to_json(const PositionWordStats& s) {
    return {{"samples", s.samples},
            {"frames", s.frames},
            {"valid_words", s.valid_words},
            {"invalid_words", s.invalid_words},
            {"not_ready", s.not_ready},
            {"no_start", s.no_start},
            {"short_frames", s.short_frames},
            {"long_frames", s.long_frames},
            {"crc_errors", s.crc_errors},
            {"error_flags", s.error_flags},
            {"out_of_range", s.out_of_range},
            {"malformed_lines", s.malformed_lines},
            {"time_reversals", s.time_reversals},
            {"warning_flags", s.warning_flags},
            {"wraps", s.wraps},
            {"min_frame_interval_s", s.frames >= 2 ? nlohmann::json(s.min_frame_interval_s) : nlohmann::json()}};  // null: no interval
}

// ---- SSI ----

SsiDecoder::SsiDecoder(SsiConfig c) : cfg_(c), angle_(c.angle, c.position_bits) {
    if (c.error_bits < 0 || c.error_bits > 8) throw std::invalid_argument("SSI readout: error_bits must be 0..8");
    check_timeout("SSI readout", c.timeout_s);
}

void SsiDecoder::process(std::size_t n, const double* t, const double* clk, const double* data, std::vector<PositionWord>& out) {
    const int frame_bits = cfg_.position_bits + cfg_.error_bits;
    for (std::size_t i = 0; i < n; ++i) {
        const bool c = clk[i] != 0, d = data[i] != 0;
        ++st_.samples;
        if (!started_) {
            started_ = true;
            prev_clk_ = c;
            last_rise_t_ = t[i];
            idle_ok_ = false;  // the capture may start inside a frame: wait for a whole timeout
            continue;
        }
        if (c && !prev_clk_) last_rise_t_ = t[i];
        if (!c && prev_clk_) {  // falling edge
            if (in_frame_) {
                if (falls_ <= frame_bits + 1) ++falls_;  // capped: a long frame stays long
                const int bit = falls_ - 2;  // falls 2 .. 1 + frame_bits carry bits 0 .. frame_bits - 1
                if (bit < cfg_.position_bits) pos_ = (pos_ << 1) | (d ? 1u : 0u);
                else if (bit < frame_bits) status_ = (status_ << 1) | (d ? 1u : 0u);
            } else if (idle_ok_ || t[i] - last_rise_t_ >= cfg_.timeout_s) {
                in_frame_ = true;
                idle_ok_ = false;
                latch_t_ = t[i];
                ready_ = d;
                falls_ = 1;
                pos_ = status_ = 0;
            }
        }
        if (c && t[i] - last_rise_t_ >= cfg_.timeout_s) {
            if (in_frame_) close_frame(out);
            idle_ok_ = true;
        }
        prev_clk_ = c;
    }
}

void SsiDecoder::close_frame(std::vector<PositionWord>& out) {
    in_frame_ = false;
    PositionWord w;
    w.t_s = latch_t_;
    const int got = falls_ - 1, want = cfg_.position_bits + cfg_.error_bits;
    if (!ready_) count_invalid(w, "not_ready", st_.not_ready, st_);
    else if (got < want) count_invalid(w, "short_frame", st_.short_frames, st_);
    else if (got > want) count_invalid(w, "long_frame", st_.long_frames, st_);
    else {
        const std::uint64_t active = cfg_.error_active_high ? status_ : (~status_ & low_mask(cfg_.error_bits));
        if (cfg_.error_bits > 0 && active != 0) count_invalid(w, "error_flag", st_.error_flags, st_);
        else w.value = cfg_.code == WordCode::gray ? gray_to_binary(pos_) : pos_;
    }
    angle_.finish_word(w, st_);
    out.push_back(w);
}

void SsiDecoder::finish(std::vector<PositionWord>& out) {
    if (in_frame_) close_frame(out);
}

nlohmann::json SsiDecoder::to_json() const {
    nlohmann::json j = {{"protocol", "ssi"},
                        {"position_bits", cfg_.position_bits},
                        {"code", code_name(cfg_.code)},
                        {"error_bits", cfg_.error_bits},
                        {"error_active_high", cfg_.error_active_high},
                        {"timeout_s", cfg_.timeout_s},
                        {"angle", angle_.to_json()}};
    j.update(fringe::to_json(st_));
    return j;
}

// ---- BiSS-C ----

namespace {
constexpr int kBissTailBits = 2 + 6;  // nE, nW, CRC6
}

BissDecoder::BissDecoder(BissConfig c) : cfg_(c), angle_(c.angle, c.position_bits) {
    if (c.max_ack_bits < 1 || c.max_ack_bits > 1024) throw std::invalid_argument("BiSS-C readout: max_ack_bits must be 1..1024");
    check_timeout("BiSS-C readout", c.timeout_s);
    bits_.reserve(static_cast<std::size_t>(1 + c.position_bits + kBissTailBits));
}

void BissDecoder::process(std::size_t n, const double* t, const double* ma, const double* slo, std::vector<PositionWord>& out) {
    const int frame_bits = 1 + cfg_.position_bits + kBissTailBits;  // CDS, data, nE, nW, CRC
    for (std::size_t i = 0; i < n; ++i) {
        const bool c = ma[i] != 0, d = slo[i] != 0;
        ++st_.samples;
        if (!started_) {
            started_ = true;
            prev_ma_ = c;
            last_rise_t_ = t[i];
            idle_ok_ = false;
            continue;
        }
        if (c && !prev_ma_) {  // rising edge: the first one of a frame latches the position
            last_rise_t_ = t[i];
            if (in_frame_ && !latched_) {
                latched_ = true;
                latch_t_ = t[i];
            }
        }
        if (!c && prev_ma_) {  // falling edge: read SLO
            if (in_frame_) {
                // Falls 1, 2, ...: with an Ack of A clocks, the Ack is read at falls 2 .. A+1 and
                // the Start bit at fall A+2; A > max_ack_bits is no_start.
                switch (phase_) {
                case Phase::request:
                case Phase::ack:
                    if (++waited_ > cfg_.max_ack_bits + 2) phase_ = Phase::overrun;
                    else if (phase_ == Phase::request && !d) phase_ = Phase::ack;
                    else if (phase_ == Phase::ack && d) phase_ = Phase::data;
                    break;
                case Phase::data:
                    if (nbits_ < frame_bits) bits_.push_back(d ? 1 : 0);
                    if (nbits_ <= frame_bits) ++nbits_;  // capped: a long frame stays long
                    break;
                case Phase::overrun:
                    break;
                }
            } else if (idle_ok_ || t[i] - last_rise_t_ >= cfg_.timeout_s) {
                in_frame_ = true;
                idle_ok_ = false;
                latched_ = false;
                ready_ = d;
                phase_ = Phase::request;
                waited_ = 0;
                nbits_ = 0;
                bits_.clear();
                latch_t_ = t[i];  // replaced by the first rising edge
            }
        }
        if (c && t[i] - last_rise_t_ >= cfg_.timeout_s) {
            if (in_frame_) close_frame(out);
            idle_ok_ = true;
        }
        prev_ma_ = c;
    }
}

void BissDecoder::close_frame(std::vector<PositionWord>& out) {
    in_frame_ = false;
    PositionWord w;
    w.t_s = latch_t_;
    const int N = cfg_.position_bits, frame_bits = 1 + N + kBissTailBits;
    if (!ready_) count_invalid(w, "not_ready", st_.not_ready, st_);
    else if (phase_ != Phase::data) count_invalid(w, "no_start", st_.no_start, st_);
    else if (nbits_ < frame_bits) count_invalid(w, "short_frame", st_.short_frames, st_);
    else if (nbits_ > frame_bits) count_invalid(w, "long_frame", st_.long_frames, st_);
    else {
        // bits_: CDS, data[N], nE, nW, CRC[6] (inverted on the wire)
        const unsigned crc = biss_crc6(bits_.data() + 1, static_cast<std::size_t>(N + 2));
        unsigned sent = 0;
        for (int k = 0; k < 6; ++k) sent = (sent << 1) | bits_[static_cast<std::size_t>(N + 3 + k)];
        const bool nE = bits_[static_cast<std::size_t>(N + 1)] != 0, nW = bits_[static_cast<std::size_t>(N + 2)] != 0;
        if ((~sent & 0x3Fu) != crc) count_invalid(w, "crc", st_.crc_errors, st_);
        else if (!nE) count_invalid(w, "error_flag", st_.error_flags, st_);
        else {
            if (!nW) ++st_.warning_flags;
            std::uint64_t v = 0;
            for (int k = 0; k < N; ++k) v = (v << 1) | bits_[static_cast<std::size_t>(1 + k)];
            w.value = cfg_.code == WordCode::gray ? gray_to_binary(v) : v;
        }
    }
    angle_.finish_word(w, st_);
    out.push_back(w);
}

void BissDecoder::finish(std::vector<PositionWord>& out) {
    if (in_frame_) close_frame(out);
}

nlohmann::json BissDecoder::to_json() const {
    nlohmann::json j = {{"protocol", "biss-c"},
                        {"position_bits", cfg_.position_bits},
                        {"code", code_name(cfg_.code)},
                        {"crc", "x^6+x+1 (0x43), start 0, inverted"},
                        {"max_ack_bits", cfg_.max_ack_bits},
                        {"timeout_s", cfg_.timeout_s},
                        {"angle", angle_.to_json()}};
    j.update(fringe::to_json(st_));
    return j;
}

// ---- SPI ----

namespace {
int spi_position_bits(const SpiConfig& c) {
    check_bits("SPI readout", "word_bits", c.word_bits);
    if (c.mode < 0 || c.mode > 3) throw std::invalid_argument("SPI readout: mode must be 0..3");
    if (c.position_shift < 0 || c.position_shift >= c.word_bits)
        throw std::invalid_argument("SPI readout: position_shift must be 0..word_bits-1");
    const int room = c.word_bits - c.position_shift;
    const int pb = c.position_bits == 0 ? room : c.position_bits;
    if (pb < 1 || pb > room) throw std::invalid_argument("SPI readout: the position field does not fit in the word");
    if (c.error_bit < -1 || c.error_bit >= c.word_bits) throw std::invalid_argument("SPI readout: error_bit must be -1..word_bits-1");
    if (c.error_bit >= c.position_shift && c.error_bit < c.position_shift + pb)
        throw std::invalid_argument("SPI readout: error_bit lies inside the position field");
    return pb;
}
// Modes 0 and 3 read on the rising edge, 1 and 2 on the falling edge.
bool spi_reads_on_rise(int mode) { return mode == 0 || mode == 3; }
}  // namespace

SpiDecoder::SpiDecoder(SpiConfig c) : cfg_(c), position_bits_(spi_position_bits(c)), angle_(c.angle, position_bits_) {}

void SpiDecoder::process(std::size_t n, const double* t, const double* cs, const double* sclk, const double* data,
                         std::vector<PositionWord>& out) {
    const bool on_rise = spi_reads_on_rise(cfg_.mode);
    for (std::size_t i = 0; i < n; ++i) {
        const bool s = cs[i] != 0, c = sclk[i] != 0, d = data[i] != 0;
        ++st_.samples;
        if (!started_) {  // a capture that starts with CS low starts inside a frame: skipped
            started_ = true;
            prev_cs_ = s;
            prev_clk_ = c;
            continue;
        }
        if (in_frame_ && c != prev_clk_ && c == on_rise) {
            if (nbits_ < 64) word_ = (word_ << 1) | (d ? 1u : 0u);  // bits in wire order
            if (nbits_ <= cfg_.word_bits) ++nbits_;
        }
        if (!s && prev_cs_) {  // CS asserted: the latch
            in_frame_ = true;
            latch_t_ = t[i];
            nbits_ = 0;
            word_ = 0;
        } else if (s && !prev_cs_ && in_frame_) {
            close_frame(out);
        }
        prev_cs_ = s;
        prev_clk_ = c;
    }
}

void SpiDecoder::close_frame(std::vector<PositionWord>& out) {
    in_frame_ = false;
    PositionWord w;
    w.t_s = latch_t_;
    if (nbits_ < cfg_.word_bits) count_invalid(w, "short_frame", st_.short_frames, st_);
    else if (nbits_ > cfg_.word_bits) count_invalid(w, "long_frame", st_.long_frames, st_);
    else {
        std::uint64_t word = word_;
        if (!cfg_.msb_first) {  // the first bit on the wire is bit 0
            std::uint64_t r = 0;
            for (int k = 0; k < cfg_.word_bits; ++k) r |= ((word >> (cfg_.word_bits - 1 - k)) & 1u) << k;
            word = r;
        }
        const bool err = cfg_.error_bit >= 0 && (((word >> cfg_.error_bit) & 1u) != 0) == cfg_.error_active_high;
        if (err) count_invalid(w, "error_flag", st_.error_flags, st_);
        else {
            const std::uint64_t v = (word >> cfg_.position_shift) & low_mask(position_bits_);
            w.value = cfg_.code == WordCode::gray ? gray_to_binary(v) : v;
        }
    }
    angle_.finish_word(w, st_);
    out.push_back(w);
}

void SpiDecoder::finish(std::vector<PositionWord>& out) {
    if (!in_frame_) return;
    in_frame_ = false;  // CS never released: the frame is cut, whatever it holds
    PositionWord w;
    w.t_s = latch_t_;
    count_invalid(w, "short_frame", st_.short_frames, st_);
    angle_.finish_word(w, st_);
    out.push_back(w);
}

nlohmann::json SpiDecoder::to_json() const {
    nlohmann::json j = {{"protocol", "spi"},
                        {"mode", cfg_.mode},
                        {"word_bits", cfg_.word_bits},
                        {"bit_order", cfg_.msb_first ? "msb-first" : "lsb-first"},
                        {"position_bits", position_bits_},
                        {"position_shift", cfg_.position_shift},
                        {"error_bit", cfg_.error_bit},
                        {"error_active_high", cfg_.error_active_high},
                        {"code", code_name(cfg_.code)},
                        {"angle", angle_.to_json()}};
    j.update(fringe::to_json(st_));
    return j;
}

// ---- Line-oriented position stream ----

namespace {
int stream_bits(const StreamConfig& c) {
    if (c.time_unit != "s" && c.time_unit != "sample")
        throw std::invalid_argument("position stream: time_unit must be \"s\" or \"sample\"");
    if (c.time_unit == "sample" && !(c.sample_rate_hz > 0 && std::isfinite(c.sample_rate_hz)))
        throw std::invalid_argument("position stream: time_unit \"sample\" needs sample_rate_hz > 0");
    if (c.max_line_bytes < 3 || c.max_line_bytes > 65536) throw std::invalid_argument("position stream: max_line_bytes must be 3..65536");
    return c.position_bits;
}

bool is_sep(char ch) { return ch == ' ' || ch == '\t'; }

// Splits a line into at most 4 fields (spaces/tabs, or one comma with optional blanks around);
// returns the field count (4 means too many).
int split_fields(const std::string& s, std::string f[4]) {
    int k = 0;
    std::size_t i = 0;
    const std::size_t n = s.size();
    while (i < n && is_sep(s[i])) ++i;
    while (i < n) {
        if (k == 4) return 4;
        std::size_t j = i;
        while (j < n && !is_sep(s[j]) && s[j] != ',') ++j;
        if (j == i) return -1;  // an empty field (",,", a leading comma)
        f[k++] = s.substr(i, j - i);
        i = j;
        while (i < n && is_sep(s[i])) ++i;
        if (i < n && s[i] == ',') {
            ++i;
            while (i < n && is_sep(s[i])) ++i;
            if (i == n) return -1;  // a trailing comma
        }
    }
    return k;
}

bool parse_u64(const std::string& s, std::uint64_t& v) {
    if (s.empty() || s.size() > 20) return false;
    std::uint64_t x = 0;
    for (char ch : s) {
        if (ch < '0' || ch > '9') return false;
        const std::uint64_t dgt = static_cast<std::uint64_t>(ch - '0');
        if (x > (std::numeric_limits<std::uint64_t>::max() - dgt) / 10) return false;
        x = x * 10 + dgt;
    }
    v = x;
    return true;
}

bool parse_double(const std::string& s, double& v) {
    if (s.empty() || s.size() > 64) return false;
    for (char ch : s)  // decimal only: no hex floats, inf, nan
        if (!((ch >= '0' && ch <= '9') || ch == '.' || ch == 'e' || ch == 'E' || ch == '+' || ch == '-')) return false;
    char* end = nullptr;
    errno = 0;
    const double x = std::strtod(s.c_str(), &end);
    if (end != s.c_str() + s.size() || errno == ERANGE || !std::isfinite(x)) return false;
    v = x;
    return true;
}
}  // namespace

PositionStreamParser::PositionStreamParser(StreamConfig c) : cfg_(c), angle_(c.angle, stream_bits(c)) {
    buf_.reserve(cfg_.max_line_bytes);
}

void PositionStreamParser::feed(const char* bytes, std::size_t n, std::vector<PositionWord>& out) {
    for (std::size_t i = 0; i < n; ++i) {
        const char ch = bytes[i];
        if (ch == '\n') {
            if (overlong_) {
                ++st_.samples;
                ++st_.malformed_lines;
                overlong_ = false;
            } else {
                line(out);
            }
            buf_.clear();
            continue;
        }
        if (overlong_) continue;
        if (buf_.size() >= cfg_.max_line_bytes) {  // bounded: the rest of the line is dropped
            overlong_ = true;
            buf_.clear();
            continue;
        }
        buf_.push_back(ch);
    }
}

void PositionStreamParser::finish(std::vector<PositionWord>& out) {
    if (overlong_) {
        ++st_.samples;
        ++st_.malformed_lines;
    } else if (!buf_.empty()) line(out);
    overlong_ = false;
    buf_.clear();
}

void PositionStreamParser::line(std::vector<PositionWord>& out) {
    ++st_.samples;
    if (!buf_.empty() && buf_.back() == '\r') buf_.pop_back();
    std::size_t first = 0;
    while (first < buf_.size() && is_sep(buf_[first])) ++first;
    if (first == buf_.size() || buf_[first] == '#') return;  // blank or comment
    std::string f[4];
    const int k = split_fields(buf_, f);
    double t = 0;
    std::uint64_t v = 0;
    bool ok = (k == 2 || (k == 3 && f[2] == "E")) && parse_u64(f[1], v);
    if (ok && cfg_.time_unit == "sample") {
        std::uint64_t idx = 0;
        ok = parse_u64(f[0], idx);
        t = static_cast<double>(idx) / cfg_.sample_rate_hz;
    } else if (ok) {
        ok = parse_double(f[0], t);
    }
    if (!ok) {
        ++st_.malformed_lines;
        return;
    }
    PositionWord w;
    w.t_s = t;
    w.value = v;
    if (have_t_ && t < last_t_) count_invalid(w, "time_reversal", st_.time_reversals, st_);
    else if (k == 3) count_invalid(w, "error_flag", st_.error_flags, st_);
    if (!(have_t_ && t < last_t_)) {
        have_t_ = true;
        last_t_ = t;
    }
    angle_.finish_word(w, st_);
    out.push_back(w);
}

nlohmann::json PositionStreamParser::to_json() const {
    nlohmann::json j = {{"protocol", "stream"},
                        {"time_unit", cfg_.time_unit},
                        {"sample_rate_hz", cfg_.sample_rate_hz},
                        {"position_bits", cfg_.position_bits},
                        {"max_line_bytes", cfg_.max_line_bytes},
                        {"angle", angle_.to_json()}};
    j.update(fringe::to_json(st_));
    j["lines"] = st_.samples;
    j.erase("samples");
    return j;
}

// ---- Settings as JSON ----

namespace {

// Reads the keys of j into a config: each key must be one `read` knows.
class Fields {
public:
    Fields(const nlohmann::json& j, const char* who) : j_(j), who_(who) {
        if (!j.is_object()) throw std::invalid_argument(std::string(who) + ": the settings must be a JSON object");
    }
    template <class T>
    void get(const char* key, T& out) {
        known_.push_back(key);
        const auto it = j_.find(key);
        if (it == j_.end()) return;
        try {
            if constexpr (std::is_same_v<T, bool>) {
                if (!it->is_boolean()) throw std::invalid_argument("not a boolean");
            } else if constexpr (std::is_integral_v<T>) {
                if (!it->is_number_integer()) throw std::invalid_argument("not an integer");
                constexpr auto hi = static_cast<std::uint64_t>(std::numeric_limits<T>::max());
                constexpr auto lo = static_cast<std::int64_t>(std::numeric_limits<T>::min());
                bool fits;
                if (it->is_number_unsigned()) {
                    fits = it->template get<std::uint64_t>() <= hi;
                } else {
                    const std::int64_t v = it->template get<std::int64_t>();
                    fits = v >= lo && (v < 0 || static_cast<std::uint64_t>(v) <= hi);
                }
                if (!fits) throw std::invalid_argument("out of range");
            } else if constexpr (std::is_floating_point_v<T>) {
                if (!it->is_number()) throw std::invalid_argument("not a number");
            } else {
                if (!it->is_string()) throw std::invalid_argument("not a string");
            }
            out = it->template get<T>();
        } catch (const std::exception& e) {
            throw std::invalid_argument(std::string(who_) + ": " + key + ": " + e.what());
        }
    }
    void code(WordCode& out) {
        std::string s = out == WordCode::gray ? "gray" : "binary";
        get("code", s);
        if (s != "binary" && s != "gray") throw std::invalid_argument(std::string(who_) + ": code must be \"binary\" or \"gray\"");
        out = s == "gray" ? WordCode::gray : WordCode::binary;
    }
    void angle(WordAngleMap& m) {
        get("counts_per_rev", m.counts_per_rev);
        get("cycles_per_rev", m.cycles_per_rev);
        get("offset_rad", m.offset_rad);
    }
    void no_others() const {
        for (const auto& kv : j_.items())
            if (std::find(known_.begin(), known_.end(), kv.key()) == known_.end()) {
                std::string keys;
                for (const std::string& k : known_) keys += (keys.empty() ? "" : ", ") + k;
                throw std::invalid_argument(std::string(who_) + ": unknown setting \"" + kv.key() + "\" (known: " + keys + ")");
            }
    }

private:
    const nlohmann::json& j_;
    const char* who_;
    std::vector<std::string> known_;
};

void put_angle(nlohmann::json& j, const WordAngleMap& m) {
    j["counts_per_rev"] = m.counts_per_rev;
    j["cycles_per_rev"] = m.cycles_per_rev;
    j["offset_rad"] = m.offset_rad;
}

}  // namespace

void to_json(nlohmann::json& j, const SsiConfig& c) {
    j = {{"position_bits", c.position_bits}, {"code", code_name(c.code)}, {"error_bits", c.error_bits},
         {"error_active_high", c.error_active_high}, {"timeout_s", c.timeout_s}};
    put_angle(j, c.angle);
}

void from_json(const nlohmann::json& j, SsiConfig& c) {
    c = SsiConfig{};
    Fields f(j, "SSI readout");
    f.get("position_bits", c.position_bits);
    f.code(c.code);
    f.get("error_bits", c.error_bits);
    f.get("error_active_high", c.error_active_high);
    f.get("timeout_s", c.timeout_s);
    f.angle(c.angle);
    f.no_others();
}

void to_json(nlohmann::json& j, const BissConfig& c) {
    j = {{"position_bits", c.position_bits}, {"code", code_name(c.code)}, {"max_ack_bits", c.max_ack_bits}, {"timeout_s", c.timeout_s}};
    put_angle(j, c.angle);
}

void from_json(const nlohmann::json& j, BissConfig& c) {
    c = BissConfig{};
    Fields f(j, "BiSS-C readout");
    f.get("position_bits", c.position_bits);
    f.code(c.code);
    f.get("max_ack_bits", c.max_ack_bits);
    f.get("timeout_s", c.timeout_s);
    f.angle(c.angle);
    f.no_others();
}

void to_json(nlohmann::json& j, const SpiConfig& c) {
    j = {{"mode", c.mode},
         {"word_bits", c.word_bits},
         {"msb_first", c.msb_first},
         {"position_bits", c.position_bits},
         {"position_shift", c.position_shift},
         {"error_bit", c.error_bit},
         {"error_active_high", c.error_active_high},
         {"code", code_name(c.code)}};
    put_angle(j, c.angle);
}

void from_json(const nlohmann::json& j, SpiConfig& c) {
    c = SpiConfig{};
    Fields f(j, "SPI readout");
    f.get("mode", c.mode);
    f.get("word_bits", c.word_bits);
    f.get("msb_first", c.msb_first);
    f.get("position_bits", c.position_bits);
    f.get("position_shift", c.position_shift);
    f.get("error_bit", c.error_bit);
    f.get("error_active_high", c.error_active_high);
    f.code(c.code);
    f.angle(c.angle);
    f.no_others();
}

void to_json(nlohmann::json& j, const StreamConfig& c) {
    j = {{"time_unit", c.time_unit}, {"sample_rate_hz", c.sample_rate_hz}, {"position_bits", c.position_bits},
         {"max_line_bytes", c.max_line_bytes}};
    put_angle(j, c.angle);
}

void from_json(const nlohmann::json& j, StreamConfig& c) {
    c = StreamConfig{};
    Fields f(j, "position stream");
    f.get("time_unit", c.time_unit);
    f.get("sample_rate_hz", c.sample_rate_hz);
    f.get("position_bits", c.position_bits);
    f.get("max_line_bytes", c.max_line_bytes);
    f.angle(c.angle);
    f.no_others();
}

// ---- Emitters ----

namespace {

struct Writer {
    const EmitterTiming& tm;
    LogicSignals& out;
    bool with_cs;
    void push(int samples, bool clk, bool data, bool cs) {
        for (int k = 0; k < samples; ++k) {
            out.t_s.push_back(static_cast<double>(out.t_s.size()) / tm.sample_rate_hz);
            out.clk.push_back(clk ? 1.0 : 0.0);
            out.data.push_back(data ? 1.0 : 0.0);
            if (with_cs) out.cs.push_back(cs ? 1.0 : 0.0);
        }
    }
    double now_s() const { return static_cast<double>(out.t_s.size()) / tm.sample_rate_hz; }
};

void check_timing(const EmitterTiming& tm) {
    if (!(tm.sample_rate_hz > 0) || tm.half_clock_samples < 1 || tm.idle_samples < 1 || tm.ack_bits < 1)
        throw std::invalid_argument("emitter: sample_rate_hz > 0, half_clock_samples >= 1, idle_samples >= 1 and ack_bits >= 1 are required");
}

int timeout_samples(double timeout_s, const EmitterTiming& tm) {
    return static_cast<int>(std::ceil(timeout_s * tm.sample_rate_hz)) + 2;
}

// An encoder driven by a clock: `pulses` pulses (falling, low, rising, high), the dropped one
// held high; the encoder sees only the pulses it gets, and bit_after(j) gives the data level
// it drives after the j-th rising edge it sees (j = 0, 1, ...). Returns the latch time (the
// first falling or rising edge, per latch_on_rise).
template <class BitAfter>
double clock_frame(Writer& w, int pulses, const WordFault& f, bool first_level, bool latch_on_rise, BitAfter bit_after) {
    const int h = w.tm.half_clock_samples;
    bool data = first_level;
    int seen = 0;
    double latch = -1;
    for (int p = 0; p < pulses; ++p) {
        if (p == f.drop_clock) {
            w.push(2 * h, true, data, true);
            continue;
        }
        if (latch < 0 && !latch_on_rise) latch = w.now_s();
        w.push(h, false, data, true);
        if (latch < 0 && latch_on_rise) latch = w.now_s();
        data = bit_after(seen++);
        w.push(h, true, data, true);
    }
    return latch;
}

}  // namespace

void emit_idle(const EmitterTiming& tm, int samples, LogicSignals& out) {
    check_timing(tm);
    const bool spi = !out.cs.empty();
    const bool c = out.clk.empty() || out.clk.back() != 0, d = out.data.empty() || out.data.back() != 0;
    Writer w{tm, out, spi};
    w.push(samples, c, d, true);
}

double emit_ssi_frame(const SsiConfig& c, const EmitterTiming& tm, std::uint64_t value, const WordFault& f, LogicSignals& out) {
    check_timing(tm);
    check_bits("SSI emitter", "position_bits", c.position_bits);
    Writer w{tm, out, false};
    const int B = c.position_bits + c.error_bits;
    const std::uint64_t pos = (c.code == WordCode::gray ? binary_to_gray(value) : value) & low_mask(c.position_bits);
    auto wire_bit = [&](int k) -> bool {  // k = 0 .. B-1: MSB first, then the status bits
        bool b;
        if (k < c.position_bits) b = ((pos >> (c.position_bits - 1 - k)) & 1u) != 0;
        else b = f.set_error ? c.error_active_high : !c.error_active_high;
        return k == f.flip_bit ? !b : b;
    };
    w.push(tm.idle_samples, true, !f.not_ready, true);
    const double latch = clock_frame(w, B + 1 + f.extra_clocks, f, !f.not_ready, false,
                                     [&](int j) { return j < B ? wire_bit(j) : false; });
    w.push(timeout_samples(c.timeout_s, tm), true, false, true);  // monoflop: data low, then idle
    return latch;
}

double emit_biss_frame(const BissConfig& c, const EmitterTiming& tm, std::uint64_t value, const WordFault& f, LogicSignals& out) {
    check_timing(tm);
    check_bits("BiSS-C emitter", "position_bits", c.position_bits);
    Writer w{tm, out, false};
    const int N = c.position_bits;
    const std::uint64_t pos = (c.code == WordCode::gray ? binary_to_gray(value) : value) & low_mask(N);
    // The bits after the start bit: CDS, data, nE, nW, ~CRC6.
    std::vector<std::uint8_t> bits;
    bits.push_back(0);
    for (int k = 0; k < N; ++k) bits.push_back(static_cast<std::uint8_t>((pos >> (N - 1 - k)) & 1u));
    bits.push_back(f.set_error ? 0 : 1);
    bits.push_back(f.set_warning ? 0 : 1);
    const unsigned crc = biss_crc6(bits.data() + 1, static_cast<std::size_t>(N + 2));
    for (int k = 5; k >= 0; --k) bits.push_back(static_cast<std::uint8_t>(((~crc) >> k) & 1u));
    if (f.flip_bit >= 0 && f.flip_bit < static_cast<int>(bits.size()))
        bits[static_cast<std::size_t>(f.flip_bit)] ^= 1u;
    const int L = static_cast<int>(bits.size());
    const int A = tm.ack_bits;
    // After rising edge j: 0 -> still ready (1), 1..A -> Ack (0), A+1 -> Start (1), then the bits, then 0 (timeout).
    auto after = [&](int j) -> bool {
        if (j == 0) return !f.not_ready;
        if (j <= A) return false;
        if (j == A + 1) return true;
        const int k = j - A - 2;
        return k < L ? bits[static_cast<std::size_t>(k)] != 0 : false;
    };
    w.push(tm.idle_samples, true, !f.not_ready, true);
    const double latch = clock_frame(w, A + L + 3 + f.extra_clocks, f, !f.not_ready, true, after);
    w.push(timeout_samples(c.timeout_s, tm), true, false, true);  // the slave's timeout: SLO low, then idle
    return latch;
}

double emit_spi_frame(const SpiConfig& c, const EmitterTiming& tm, std::uint64_t value, const WordFault& f, LogicSignals& out) {
    check_timing(tm);
    const int pb = spi_position_bits(c);
    Writer w{tm, out, true};
    const int W = c.word_bits, h = tm.half_clock_samples;
    const bool cpol = c.mode >= 2, cpha = (c.mode & 1) != 0;
    std::uint64_t word = ((c.code == WordCode::gray ? binary_to_gray(value) : value) & low_mask(pb)) << c.position_shift;
    if (c.error_bit >= 0 && f.set_error == c.error_active_high) word |= std::uint64_t{1} << c.error_bit;
    auto wire_bit = [&](int k) -> bool {  // k-th bit on the wire
        if (k >= W) return false;
        const int b = c.msb_first ? W - 1 - k : k;
        const bool v = ((word >> b) & 1u) != 0;
        return k == f.flip_bit ? !v : v;
    };
    w.push(tm.idle_samples, cpol, false, true);
    const double latch = w.now_s();
    int seen = 0;  // clock pulses the slave has seen
    bool data = cpha ? false : wire_bit(0);
    w.push(h, cpol, data, false);
    const int pulses = W + f.extra_clocks;
    for (int p = 0; p < pulses; ++p) {
        if (p == f.drop_clock) {
            w.push(2 * h, cpol, data, false);
            continue;
        }
        // leading edge: CPHA 1 shifts out bit `seen`; trailing edge: CPHA 0 shifts out the next bit
        if (cpha) data = wire_bit(seen);
        w.push(h, !cpol, data, false);
        if (!cpha) data = wire_bit(seen + 1);
        w.push(h, cpol, data, false);
        ++seen;
    }
    w.push(h, cpol, data, true);
    return latch;
}

}  // namespace fringe
