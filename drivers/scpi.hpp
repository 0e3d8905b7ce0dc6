// SCPI transport for bench instruments (issue 14, docs/bench.md): raw TCP sockets (port 5025,
// Red Pitaya 5000) and USBTMC over libusb, IEEE 488.2 definite-length (`#<n><len><data>`) and
// indefinite (`#0`) binary blocks both ways, `*IDN?`, `*OPC?` and the error queue
// (`SYST:ERR?`) read after every command that can fail, with the instrument's own error text in
// the DeviceError. Every read has a deadline; a timeout names the command it waited for.
// The block and USBTMC framing helpers are pure functions (unit-tested, fuzzed).
#pragma once

#include "device.hpp"

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace fringe::dev::scpi {

// ---- IEEE 488.2 arbitrary blocks (7.7.6 definite length, 7.7.6.2 indefinite) ----

// `#<n><len><data>` with n = digits of len (1..9).
std::string encode_block(std::string_view data);

struct BlockHeader {
    enum class Status { Ok, NeedMore, Bad };
    Status status = Status::NeedMore;
    std::size_t header_bytes = 0;  // '#', the digit count and the length digits
    std::size_t data_bytes = 0;    // definite: the declared length
    bool indefinite = false;       // `#0`: data runs to the end of the message
    std::string error;             // Bad: why
};
// Parses the header at the start of buf (leading spaces skipped and counted in header_bytes).
// Hostile input: a non-digit count or length, a count of 0 is indefinite, a declared length
// above max_bytes is Bad (never allocated).
BlockHeader parse_block_header(std::string_view buf, std::size_t max_bytes);

// A whole response holding one block (`#...` then an optional "\n"): the data, or throws
// std::runtime_error naming what is wrong (truncated, too long, trailing bytes).
std::string decode_block(std::string_view response, std::size_t max_bytes);

// `SYST:ERR?` answer `-113,"Undefined header"` -> code and text; code 0 is no error.
// Throws std::runtime_error when it is not of that form.
struct ErrorEntry {
    int code = 0;
    std::string text;
};
ErrorEntry parse_error_entry(std::string_view reply);

// ---- USBTMC (USB Test & Measurement Class 1.0, 3.2 Bulk-OUT / 3.3 Bulk-IN) ----
namespace usbtmc {
constexpr std::uint8_t kDevDepMsgOut = 1, kRequestDevDepMsgIn = 2, kDevDepMsgIn = 2;
constexpr std::size_t kHeaderBytes = 12;
// The next bTag after tag: 1..255, never 0 (3.2.1.1).
std::uint8_t next_tag(std::uint8_t tag);
// DEV_DEP_MSG_OUT: header, the message bytes, zero padding to a multiple of 4 (3.2.1.1).
std::vector<std::uint8_t> encode_out(std::uint8_t tag, std::string_view data, bool eom);
// REQUEST_DEV_DEP_MSG_IN asking for at most max_bytes (3.2.1.2); term_char when enabled.
std::array<std::uint8_t, kHeaderBytes> encode_request_in(std::uint8_t tag, std::uint32_t max_bytes, std::optional<char> term_char = std::nullopt);
struct InHeader {
    std::uint8_t tag = 0;
    std::uint32_t transfer_size = 0;
    bool eom = false;
};
// DEV_DEP_MSG_IN header (3.3.1.1): throws std::runtime_error when the MsgID, bTag,
// bTagInverse or reserved bytes are wrong, or the size exceeds what was asked for.
InHeader decode_in_header(const std::uint8_t* p, std::size_t n, std::uint8_t expected_tag, std::uint32_t asked);
}  // namespace usbtmc

// ---- Byte links ----

// One message-oriented link to an instrument. A message is written whole (TCP appends the
// "\n" terminator; USBTMC sets EOM). read_some returns at least one byte or throws on the
// deadline (TimeoutError) or a lost link; *end is set when the byte ends a message (TCP: never
// known, the caller looks for "\n"; USBTMC: EOM).
class TimeoutError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};
class Link {
public:
    virtual ~Link() = default;
    virtual void write_message(std::string_view bytes, double timeout_s) = 0;
    virtual std::size_t read_some(char* buf, std::size_t n, double timeout_s, bool* end) = 0;
    virtual std::string describe() const = 0;  // "127.0.0.1:5025", "USBTMC 0957:2b07"
    virtual bool message_framed() const = 0;    // USBTMC: EOM marks message ends
};
// Throws std::runtime_error naming the endpoint and errno's text.
std::unique_ptr<Link> connect_tcp(const std::string& host, int port, double timeout_s);
std::unique_ptr<Link> open_usbtmc(std::uint16_t vid, std::uint16_t pid, const std::string& serial, double timeout_s);

// Caps on text an instrument sends (a reply longer than its cap is an error, "reply longer than
// N bytes", and no more than the cap is ever buffered for it).
constexpr std::size_t kMaxIdnBytes = 256;         // *IDN?
constexpr std::size_t kMaxErrorLineBytes = 1024;  // one SYST:ERR? entry
constexpr std::size_t kMaxReplyBytes = 64 * 1024; // any other line (query()); data lines name their own

// A Session's read or write ran past its deadline (the instrument is silent or busy).
class InstrumentTimeout : public DeviceError {
public:
    using DeviceError::DeviceError;
};

// ---- A SCPI session: lines, blocks, the error queue ----
class Session {
public:
    Session(std::unique_ptr<Link> link, std::string device_uri, double timeout_s, std::size_t max_block_bytes);
    const std::string& uri() const { return uri_; }
    double timeout_s() const { return timeout_s_; }
    void set_timeout_s(double t) { timeout_s_ = t; }

    // Raw: no error check. read_line refuses a line longer than max_bytes (0: the block cap).
    void send(std::string_view command);
    std::string read_line(std::string_view waited_for, std::size_t max_bytes = 0);
    std::string read_block(std::string_view waited_for);

    // Commands that can fail: send, then drain the error queue; a non-zero entry throws
    // DeviceError "instrument error after 'CMD': -222,"Data out of range"".
    void command(std::string_view cmd);
    std::string query(std::string_view q, std::size_t max_bytes = kMaxReplyBytes);  // a line (checked)
    std::string query_block(std::string_view q);  // a block (checked)
    void check_errors(std::string_view after);
    // *OPC?: waits (up to timeout) until pending operations are done.
    void sync(double timeout_s);
    // *IDN?, at most kMaxIdnBytes, its control characters and bytes that are not UTF-8 escaped
    // (\x1b, \xff): it becomes the run's DUT and device description.
    std::string identify();

    // Checks the error queue after each command (default); off for instruments without one.
    bool error_queue = true;

private:
    [[noreturn]] void fail(std::string_view what, const std::exception& e);
    // Reads at most max_n more bytes before deadline; false on the deadline.
    bool fill(std::string_view waited_for, std::size_t max_n, std::chrono::steady_clock::time_point deadline);
    void check_usable() const;
    std::unique_ptr<Link> link_;
    std::string uri_;
    double timeout_s_;
    std::size_t max_block_;
    std::string buf_;  // bytes read and not yet consumed
    std::size_t pos_ = 0;
    bool at_end_ = false;  // USBTMC: the buffered bytes end a message
    std::string broken_;   // why the reply stream lost its framing (a reply over its cap): no more I/O
};

}  // namespace fringe::dev::scpi
