// SCPI transport pieces without an instrument: IEEE 488.2 blocks (hostile input), the error
// queue's entries, USBTMC Bulk-OUT/IN framing against USBTMC 1.0 tables 1-3 and 8-9, the
// emulator's interpolator against analytic truth, and a Session over a scripted link (reply
// caps, escaped instrument text, truncated blocks).
#include "drivers/sim/instrument_sim.hpp"
#include "drivers/scpi.hpp"
#include "signal_gen/base/text.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <functional>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_scpi_cpp {

using namespace fringe::dev;
using namespace fringe::dev::scpi;

TEST_CASE("scpi: definite blocks encode and decode", "[scpi]") {
    CHECK(encode_block("") == "#10");
    CHECK(encode_block("abc") == "#13abc");
    const std::string big(123456, '\n');  // data bytes that look like terminators
    const std::string e = encode_block(big);
    CHECK(e.substr(0, 8) == "#6123456");
    CHECK(decode_block(e + "\n", 1 << 20) == big);
    CHECK(decode_block("#0hello\n", 100) == "hello");
}

TEST_CASE("scpi: hostile block headers are refused, never allocated", "[scpi][hostile]") {
    CHECK_THROWS_WITH(decode_block("#9999999999", 1 << 20), Catch::Contains("more than the 1048576 allowed"));
    CHECK_THROWS_WITH(decode_block("#15abc", 100), Catch::Contains("truncated block: 3 of 5"));
    CHECK_THROWS_WITH(decode_block("#1", 100), Catch::Contains("truncated block header"));
    CHECK_THROWS_WITH(decode_block("#a5", 100), Catch::Contains("digit count"));
    CHECK_THROWS_WITH(decode_block("#21x", 100), Catch::Contains("non-digit"));
    CHECK_THROWS_WITH(decode_block("13abc", 100), Catch::Contains("starts with '#'"));
    CHECK_THROWS_WITH(decode_block("#13abcXYZ", 100), Catch::Contains("3 unexpected bytes"));
    CHECK(parse_block_header("#3", 100).status == BlockHeader::Status::NeedMore);
    CHECK(parse_block_header("  #3100", 100).header_bytes == 7);
}

TEST_CASE("scpi: error queue entries", "[scpi]") {
    auto e = parse_error_entry("-113,\"Undefined header\"\n");
    CHECK(e.code == -113);
    CHECK(e.text == "Undefined header");
    CHECK(parse_error_entry("+0,\"No error\"").code == 0);
    CHECK(parse_error_entry("0").code == 0);
    CHECK_THROWS(parse_error_entry("OK"));
    CHECK_THROWS(parse_error_entry(""));
    CHECK_THROWS(parse_error_entry("99999999999,\"x\""));
}

TEST_CASE("scpi: USBTMC Bulk-OUT DEV_DEP_MSG_OUT framing", "[scpi][usbtmc]") {
    const auto p = usbtmc::encode_out(0x5B, "*IDN?\n", true);
    REQUIRE(p.size() == 12 + 8);  // 6 data bytes padded to a multiple of 4
    CHECK(p[0] == 1);             // MsgID DEV_DEP_MSG_OUT
    CHECK(p[1] == 0x5B);
    CHECK(p[2] == 0xA4);  // bTagInverse (the spec's own example)
    CHECK(p[3] == 0);
    CHECK((p[4] | p[5] << 8 | p[6] << 16 | p[7] << 24) == 6);  // TransferSize, little-endian
    CHECK(p[8] == 1);  // EOM
    CHECK((p[9] | p[10] | p[11]) == 0);
    CHECK(std::string(p.begin() + 12, p.begin() + 18) == "*IDN?\n");
    CHECK((p[18] | p[19]) == 0);
    CHECK(usbtmc::encode_out(7, "abcd", false)[8] == 0);
    CHECK(usbtmc::encode_out(7, "abcd", false).size() == 16);
    CHECK_THROWS(usbtmc::encode_out(0, "x", true));
    CHECK(usbtmc::next_tag(1) == 2);
    CHECK(usbtmc::next_tag(255) == 1);  // never 0
}

TEST_CASE("scpi: USBTMC REQUEST_DEV_DEP_MSG_IN and the DEV_DEP_MSG_IN header", "[scpi][usbtmc]") {
    const auto r = usbtmc::encode_request_in(9, 0x01020304, '\n');
    CHECK(r[0] == 2);
    CHECK(r[1] == 9);
    CHECK(r[2] == static_cast<std::uint8_t>(~9));
    CHECK(r[4] == 4);
    CHECK(r[7] == 1);
    CHECK(r[8] == 2);  // TermCharEnabled
    CHECK(r[9] == '\n');
    CHECK(usbtmc::encode_request_in(9, 100)[8] == 0);
    std::uint8_t in[12] = {2, 9, static_cast<std::uint8_t>(~9), 0, 5, 0, 0, 0, 1, 0, 0, 0};
    const auto h = usbtmc::decode_in_header(in, 12, 9, 100);
    CHECK(h.transfer_size == 5);
    CHECK(h.eom);
    CHECK_THROWS_WITH(usbtmc::decode_in_header(in, 12, 10, 100), Catch::Contains("bTag"));
    CHECK_THROWS_WITH(usbtmc::decode_in_header(in, 12, 9, 4), Catch::Contains("exceeds"));
    CHECK_THROWS_WITH(usbtmc::decode_in_header(in, 11, 9, 100), Catch::Contains("shorter"));
    in[0] = 1;
    CHECK_THROWS_WITH(usbtmc::decode_in_header(in, 12, 9, 100), Catch::Contains("MsgID"));
    in[0] = 2;
    in[10] = 1;
    CHECK_THROWS_WITH(usbtmc::decode_in_header(in, 12, 9, 100), Catch::Contains("reserved"));
}

TEST_CASE("scpi: the emulator's interpolator reproduces a band-limited tone between samples", "[scpi]") {
    // A cyclic tone at 0.1 cycles/sample: the Kaiser-sinc value at fractional positions matches
    // the closed form to 1e-4 away from the start (before it the output is idle: 0).
    std::vector<double> x(1000);
    for (std::size_t k = 0; k < x.size(); ++k) x[k] = std::sin(2 * M_PI * 0.1 * static_cast<double>(k));
    double emax = 0;
    for (double u = 100.0; u < 3000.0; u += 0.37) emax = std::max(emax, std::fabs(sim_interpolate(x, true, u) - std::sin(2 * M_PI * 0.1 * u)));
    CHECK(emax < 1e-4);
    CHECK(sim_interpolate(x, true, 40.0) == Approx(x[40]).margin(1e-12));  // integer positions hit the samples
    CHECK(sim_interpolate(x, false, -20.0) == 0.0);
    CHECK(sim_interpolate(x, false, 1020.0) == 0.0);  // played once: idle after the end
}

// ---- A Session over a scripted link: caps, escaping, truncated blocks (issue 21) ----
namespace {
// Answers each message from a script; "*IDN?" may be an endless line. Counts what it handed out.
class ScriptLink final : public Link {
public:
    std::function<std::string(const std::string&)> answer;
    bool endless_idn = false;
    std::size_t delivered = 0, largest_read = 0;
    void write_message(std::string_view bytes, double) override {
        const std::string m(bytes);
        if (m == "*IDN?" && endless_idn) endless_ = true;
        else out_ += answer(m);
    }
    std::size_t read_some(char* buf, std::size_t n, double, bool* end) override {
        *end = false;
        largest_read = std::max(largest_read, n);
        if (endless_) {
            std::memset(buf, 'x', n);
            delivered += n;
            return n;
        }
        if (out_.empty()) throw TimeoutError("no reply within 0.1 s");
        const std::size_t k = std::min(n, out_.size());
        std::memcpy(buf, out_.data(), k);
        out_.erase(0, k);
        delivered += k;
        return k;
    }
    std::string describe() const override { return "script"; }
    bool message_framed() const override { return false; }

private:
    std::string out_;
    bool endless_ = false;
};
}  // namespace

TEST_CASE("scpi: an endless *IDN? line is refused at 256 bytes, never buffered beyond", "[scpi][hostile]") {
    auto link = std::make_unique<ScriptLink>();
    ScriptLink* l = link.get();
    l->endless_idn = true;
    l->answer = [](const std::string&) { return std::string("0,\"No error\"\n"); };
    Session s(std::move(link), "scpi+tcp://script", 0.1, 1 << 20);
    std::string msg;
    try {
        s.identify();
    } catch (const fringe::dev::DeviceError& e) {
        msg = e.what();
    }
    CHECK_THAT(msg, Catch::Contains("reply longer than 256 bytes"));
    CHECK(msg.size() < 600);  // the error quotes 60 bytes of it, not all
    CHECK(l->delivered <= kMaxIdnBytes + 2);
    // The rest of that line is still on the wire: the session refuses to go on out of step.
    CHECK_THROWS_WITH(s.command("*CLS"), Catch::Contains("out of step"));
}

TEST_CASE("scpi: error-queue text is kept whole past a NUL and escaped, capped at 1 KiB", "[scpi][hostile]") {
    auto link = std::make_unique<ScriptLink>();
    int n = 0;
    link->answer = [&](const std::string& m) {
        if (m != "SYST:ERR?") return std::string();
        return ++n == 1 ? std::string("-200,\"bad \x1b[2J\x1b]0;t\x07 red\0kept\xff\"\n", 32) : std::string("0,\"No error\"\n");
    };
    Session s(std::move(link), "scpi+tcp://script", 0.1, 1 << 20);
    std::string msg;
    try {
        s.command("X");
    } catch (const fringe::dev::DeviceError& e) {
        msg = e.what();
    }
    CHECK_THAT(msg, Catch::Contains("-200,\"bad \\x1b[2J\\x1b]0;t\\x07 red\\x00kept\\xff\""));
    CHECK(msg.find('\x1b') == std::string::npos);

    auto link2 = std::make_unique<ScriptLink>();
    link2->answer = [](const std::string& m) { return m == "SYST:ERR?" ? "-200,\"" + std::string(5000, 'e') + "\"\n" : std::string(); };
    Session s2(std::move(link2), "scpi+tcp://script", 0.1, 1 << 20);
    CHECK_THROWS_WITH(s2.command("X"), Catch::Contains("reply longer than 1024 bytes"));
}

TEST_CASE("scpi: a block that stops part way is reported truncated with its counts", "[scpi][hostile]") {
    auto link = std::make_unique<ScriptLink>();
    link->answer = [](const std::string& m) { return m == ":WAV:DATA?" ? std::string("#210abcd") : std::string(); };
    Session s(std::move(link), "scpi+tcp://script", 0.1, 1 << 20);
    s.send(":WAV:DATA?");
    CHECK_THROWS_WITH(s.read_block(":WAV:DATA?"), Catch::Contains("truncated block: 4 of 10 declared bytes arrived within 0.1 s"));
}

TEST_CASE("text: term_escape shows every control visibly and keeps the rest", "[scpi][text]") {
    CHECK(fringe::term_escape("plain UTF-8: \xc3\xa9\xe2\x82\xac \\path") == "plain UTF-8: \xc3\xa9\xe2\x82\xac \\path");
    CHECK(fringe::term_escape(std::string("a\x1b[2Jb\0c\x7f\xff\r\n\t", 13)) == "a\\x1b[2Jb\\x00c\\x7f\\xff\\r\\n\\t");
    CHECK(fringe::term_escape("C1 \xc2\x9b" "2J bidi \xe2\x80\xae!") == "C1 \\u009b2J bidi \\u202e!");
    CHECK(fringe::term_escape("two\nlines", true) == "two\nlines");
    CHECK(fringe::log_escape("x\\y\xc2\x85") == "x\\\\y\\u0085");
}

}  // namespace test_scpi_cpp
