// SCPI transport pieces without an instrument: IEEE 488.2 blocks (hostile input), the error
// queue's entries, USBTMC Bulk-OUT/IN framing against USBTMC 1.0 tables 1-3 and 8-9, and the
// emulator's interpolator against analytic truth.
#include "drivers/instrument_sim.hpp"
#include "drivers/scpi.hpp"

#include <catch2/catch.hpp>

#include <cmath>

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
