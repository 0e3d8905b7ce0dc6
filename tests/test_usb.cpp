// The USB driver against the emulated board (libumockdev), run under umockdev's preload:
// identification, a streamed loopback, exact drop counts, underflow, stall, silence, unplug.
// Registered in ctest with LD_PRELOAD=libumockdev-preload.so.0 (label usb) and
// FRINGE_USB_EMULATOR_CLOCK=paced: the board's clock follows the host, so a CI host that
// stalls cannot fail a test about something else. The tests about timing (a host that falls
// behind, a board that runs dry) ask for the real-time clock themselves.
#include "drivers/device.hpp"
#include "drivers/sim/usb_emulator.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/constants.hpp"

#include <catch2/catch.hpp>

#include <atomic>
#include <chrono>
#include <cmath>
#include <thread>
#include <vector>

using namespace fringe;
using namespace fringe::dev;
using clk = std::chrono::steady_clock;

namespace {

struct Stream {
    std::vector<double> s, c;
    explicit Stream(std::size_t n, double f = 0.01) : s(n), c(n) {
        for (std::size_t k = 0; k < n; ++k) {
            s[k] = 0.9 * std::sin(2 * kPi * f * static_cast<double>(k));
            c[k] = 0.9 * std::cos(2 * kPi * f * static_cast<double>(k));
        }
    }
};

// Writes everything, one block ahead of what it reads back (a real-time board must never run
// dry); returns the first non-Ok status (or Ok with all frames).
StreamResult loop(StreamPort& d, const Stream& in, std::vector<double>& rs, std::vector<double>& rc, std::size_t block = 8192) {
    rs.assign(in.s.size(), 0);
    rc.assign(in.s.size(), 0);
    std::size_t got = 0, put = 0;
    while (got < in.s.size()) {
        while (put < in.s.size() && put < got + 2 * block) {
            const std::size_t n = std::min(block, in.s.size() - put);
            const auto w = d.write(std::span(in.s).subspan(put, n), std::span(in.c).subspan(put, n));
            if (w.status != StreamStatus::Ok) return w;
            put += n;
            if (put == in.s.size()) d.end_of_output();  // the last, short frame goes now
        }
        const std::size_t want = std::min(block, put - got);
        const auto r = d.read(std::span(rs).subspan(got, want), std::span(rc).subspan(got, want), 1000);
        if (r.status != StreamStatus::Ok) return r;
        got += r.frames;
    }
    return {StreamStatus::Ok, got, 0, 0, ""};
}
}  // namespace

TEST_CASE("usb: the emulated board identifies itself and selects by serial", "[usb]") {
    UsbEmulator emu(parse_usb_emulator_options("serial=B0042"));
    auto d = open("usb:1209:ec01");
    const auto i = d->info();
    CHECK(i.driver == "usb");
    CHECK(i.streaming);
    // The ports docs/architecture.md lists for usb ("Device capabilities"): streams only.
    CHECK(i.ports() == std::vector<std::string>{"stream"});
    CHECK((d->step() == nullptr && d->player() == nullptr && d->recorder() == nullptr && d->replay() == nullptr));
    CHECK(i.board_id == "fringe-usb-sim#B0042");
    CHECK(open("usb:1209:ec01?serial=B0042")->info().board_id == "fringe-usb-sim#B0042");
    CHECK_THROWS_WITH(open("usb:1209:ec01?serial=NOPE"), Catch::Contains("no fringe USB board 1209:ec01 with serial NOPE"));
    CHECK_THROWS_WITH(open("usb:dead:beef"), Catch::Contains("no fringe USB board dead:beef"));
    CHECK_THROWS_WITH(open("usb:xyz"), Catch::Contains("usb:VID:PID"));
    CHECK_THROWS_AS(d->stream()->start(50e6), DeviceError);  // beyond max_rate_hz
}

TEST_CASE("usb: a streamed loopback returns what was written, in order", "[usb]") {
    UsbEmulator emu(parse_usb_emulator_options("adc_bits=16"));
    auto d = open("usb:1209:ec01?transfers=16");
    d->stream()->start(200000.0);
    Stream in(60000);
    std::vector<double> rs, rc;
    const auto r = loop(*d->stream(), in, rs, rc);
    d->stream()->stop();
    REQUIRE(r.status == StreamStatus::Ok);
    double emax = 0;
    for (std::size_t k = 0; k < in.s.size(); ++k) emax = std::max({emax, std::fabs(rs[k] - in.s[k]), std::fabs(rc[k] - in.c[k])});
    CHECK(emax <= 1.25 / 32768);  // int16 codes both ways: within one code
    const auto st = emu.status();
    CHECK(st.in_dropped == 0);
    CHECK(st.underflows <= 1);  // the last partial frame may run dry before stop
}

TEST_CASE("usb: a paced board waits for a host that pauses, and loses nothing", "[usb]") {
    UsbEmulator emu(parse_usb_emulator_options("clock=paced"));
    auto d = open("usb:1209:ec01?frame_samples=500&transfers=2");
    d->stream()->start(100000.0);
    Stream in(8000);
    REQUIRE(d->stream()->write(in.s, in.c).status == StreamStatus::Ok);
    d->stream()->end_of_output();
    // On the real-time clock this pause loses frames (the test above); paced, the board waits.
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    std::vector<double> rs(8000), rc(8000);
    std::size_t got = 0;
    while (got < 8000) {
        const auto r = d->stream()->read(std::span(rs).subspan(got), std::span(rc).subspan(got), 1000);
        REQUIRE(r.status == StreamStatus::Ok);
        got += r.frames;
    }
    d->stream()->stop();
    CHECK(rs[7999] == Approx(in.s[7999]).margin(1.25 / 32768));
    const auto st = emu.status();
    CHECK(st.in_dropped == 0);
    CHECK(st.underflows == 0);
    CHECK(st.in_frames == 16);
}

TEST_CASE("usb: the emulator's clock is named, and a wrong name is refused", "[usb]") {
    CHECK(parse_usb_emulator_options("clock=paced").clock == UsbEmulatorOptions::Clock::Paced);
    CHECK(parse_usb_emulator_options("clock=realtime").clock == UsbEmulatorOptions::Clock::Realtime);
    CHECK_THROWS_WITH(parse_usb_emulator_options("clock=wall"), Catch::Contains("clock=wall"));
}

TEST_CASE("usb: frames the board drops are counted exactly", "[usb]") {
    UsbEmulator emu(parse_usb_emulator_options("drop_at=5,drop_count=3"));
    auto d = open("usb:1209:ec01?frame_samples=1000");
    d->stream()->start(200000.0);
    Stream in(40000);
    std::vector<double> rs, rc;
    const auto r = loop(*d->stream(), in, rs, rc);
    d->stream()->stop();
    REQUIRE(r.status == StreamStatus::Overflow);
    CHECK(r.dropped == 3000);   // 3 frames of 1000 sample pairs
    CHECK(r.first_index == 5000);
    CHECK(r.message.find("IN frames 5..7") != std::string::npos);
}

TEST_CASE("usb: a host that does not keep up loses frames, and knows how many", "[usb]") {
    UsbEmulator emu(parse_usb_emulator_options("clock=realtime"));
    auto d = open("usb:1209:ec01?frame_samples=500&transfers=2");
    d->stream()->start(100000.0);
    Stream in(8000);  // 16 frames: the board's FIFO holds them all
    REQUIRE(d->stream()->write(in.s, in.c).status == StreamStatus::Ok);
    // ~60 frames due, 2 transfers waiting (longer when the board's clock is slowed down)
    std::this_thread::sleep_for(std::chrono::duration<double>(0.3 / UsbEmulatorOptions::default_time_scale()));
    std::vector<double> rs(100000), rc(100000);
    StreamResult r;
    for (int i = 0; i < 50; ++i) {
        r = d->stream()->read(rs, rc, 200);
        if (r.status != StreamStatus::Ok) break;
    }
    d->stream()->stop();
    CHECK(r.status == StreamStatus::Overflow);
    CHECK(r.dropped > 0);
    CHECK(r.dropped % 500 == 0);
    CHECK(emu.status().in_dropped >= r.dropped / 500);
}

TEST_CASE("usb: running out of DAC samples is an underflow", "[usb]") {
    UsbEmulator emu(parse_usb_emulator_options("clock=realtime"));
    auto d = open("usb:1209:ec01?frame_samples=1000");
    d->stream()->start(100000.0);
    Stream in(2000);
    REQUIRE(d->stream()->write(in.s, in.c).status == StreamStatus::Ok);  // two whole frames, then nothing
    std::vector<double> rs(5000), rc(5000);
    StreamResult r;
    std::size_t got = 0;
    for (int i = 0; i < 10; ++i) {
        r = d->stream()->read(rs, rc, 500);
        if (r.status != StreamStatus::Ok) break;
        got += r.frames;
    }
    d->stream()->stop();
    CHECK(got == 2000);  // what was written came back first
    CHECK(r.status == StreamStatus::Underflow);
    CHECK(emu.status().underflows >= 1);
}

TEST_CASE("usb: stall, silence and unplug are errors, unplug within 1 s", "[usb]") {
    std::vector<double> rs, rc;
    SECTION("stall") {
        UsbEmulator emu(parse_usb_emulator_options("stall_after=4"));
        auto d = open("usb:1209:ec01?frame_samples=1000");
        d->stream()->start(100000.0);
        const auto r = loop(*d->stream(), Stream(20000), rs, rc);
        CHECK(r.status == StreamStatus::Error);
        CHECK(r.message == "stall on IN endpoint 0x81");
    }
    SECTION("the board goes silent") {
        UsbEmulator emu(parse_usb_emulator_options("silent_after=3"));
        auto d = open("usb:1209:ec01?frame_samples=1000&timeout_ms=200");
        d->stream()->start(100000.0);
        const auto r = loop(*d->stream(), Stream(20000), rs, rc);
        CHECK((r.status == StreamStatus::Timeout));
    }
    SECTION("unplugged mid-stream") {
        UsbEmulator emu(parse_usb_emulator_options(""));
        auto d = open("usb:1209:ec01?frame_samples=1000");
        d->stream()->start(100000.0);
        Stream in(1000000);
        std::atomic<clk::rep> unplugged_at{0};
        std::thread pull([&] {
            std::this_thread::sleep_for(std::chrono::milliseconds(100));
            emu.unplug();
            unplugged_at = clk::now().time_since_epoch().count();
        });
        const auto r = loop(*d->stream(), in, rs, rc, 4000);
        const auto t_err = clk::now();
        pull.join();
        CHECK(r.status == StreamStatus::Error);
        CHECK(r.message.find("device unplugged") != std::string::npos);
        const double after_s = std::chrono::duration<double>(t_err.time_since_epoch() - clk::duration(unplugged_at.load())).count();
        CHECK(after_s < 1.0);
    }
}
