// Driver conformance (libiio's habit): the same tests against every driver that can run in
// CI, selected by FRINGE_TEST_URI (tests/conformance.sh sets up each backend: loopback,
// capture, modbus over TCP and over RTU against board-sim). Every device must describe
// itself, reject unknown settings by name, have a null port for each capability it lacks
// (never a port that does nothing), and carry a known signal through each port it has.
#include "drivers/device.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/constants.hpp"

#include <catch2/catch.hpp>

#include "drivers/sim/instrument_sim.hpp"

#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <sstream>
#include <thread>
#include <memory>
#include <string>
#include <vector>

using namespace fringe;
using namespace fringe::dev;

#ifdef FRINGE_WITH_USB_EMULATOR
#include "drivers/sim/usb_emulator.hpp"
#endif

namespace {
#ifdef FRINGE_WITH_USB_EMULATOR
// The usb backend: the emulated board lives in this process (run under umockdev's preload).
const std::unique_ptr<UsbEmulator> g_usb = std::getenv("FRINGE_TEST_USB_EMULATOR") ? std::make_unique<UsbEmulator>(UsbEmulatorOptions{}) : nullptr;
#endif
std::string uri() {
    const char* u = std::getenv("FRINGE_TEST_URI");
    return u ? u : "loopback:";
}
std::string with_setting(const std::string& u, const std::string& kv) { return u + (u.find('?') == std::string::npos ? "?" : "&") + kv; }
}  // namespace

TEST_CASE("conformance: the device describes itself", "[conformance]") {
    INFO(uri());
    auto d = open(uri());
    const auto i = d->info();
    CHECK_FALSE(i.driver.empty());
    CHECK(i.uri == uri());
    CHECK_FALSE(i.board_id.empty());
    CHECK_FALSE(i.ports().empty());
    CHECK(i.latency_samples >= 0);
    bool listed = false;
    for (const auto& drv : drivers()) listed |= uri().rfind(drv.scheme + ":", 0) == 0 && !drv.summary.empty();
    CHECK(listed);
}

TEST_CASE("conformance: unknown settings are errors naming the key", "[conformance]") {
    CHECK_THROWS_WITH(open(with_setting(uri(), "no_such_setting=1")), Catch::Contains("device.no_such_setting"));
}

TEST_CASE("conformance: the capabilities it reports are its ports", "[conformance]") {
    auto d = open(uri());
    const auto i = d->info();
    CHECK(i.streaming == (d->stream() != nullptr));
    CHECK(i.step_mode == (d->step() != nullptr));
    CHECK(i.can_play == (d->player() != nullptr));
    CHECK(i.can_record == (d->recorder() != nullptr));
    CHECK(i.replay == (d->replay() != nullptr));
    // A replay is an input-only source: nothing to write to, nothing to step.
    if (d->replay()) CHECK((d->stream() == nullptr && d->step() == nullptr && d->player() == nullptr));
    const nlohmann::json j = i;
    CHECK(j.at("ports") == nlohmann::json(i.ports()));
}

TEST_CASE("conformance: a known signal goes through", "[conformance]") {
    INFO(uri());
    auto d = open(uri());
    const auto i = d->info();
    if (StreamPort* st = d->stream()) {  // a loop: what was written comes back (after the declared latency)
        const std::size_t n = 4000;
        std::vector<double> s(n), c(n), rs(n), rc(n);
        for (std::size_t k = 0; k < n; ++k) {
            s[k] = 0.9 * std::sin(2 * kPi * static_cast<double>(k) / 200.0);
            c[k] = 0.9 * std::cos(2 * kPi * static_cast<double>(k) / 200.0);
        }
        st->start(100000.0);
        REQUIRE(st->write(s, c).status == StreamStatus::Ok);
        st->end_of_output();
        std::size_t got = 0;
        while (got < n) {
            const auto r = st->read(std::span(rs).subspan(got), std::span(rc).subspan(got), 1000);
            REQUIRE(r.status == StreamStatus::Ok);
            REQUIRE(r.dropped == 0);
            REQUIRE(r.frames > 0);
            got += r.frames;
        }
        st->stop();
        double amp2 = 0;
        for (std::size_t k = 0; k < got; ++k) {
            REQUIRE(std::isfinite(rs[k]));
            REQUIRE(std::isfinite(rc[k]));
            amp2 += rs[k] * rs[k] + rc[k] * rc[k];
        }
        CHECK(std::sqrt(amp2 / static_cast<double>(got)) > 0.05);
        const std::size_t lat = static_cast<std::size_t>(i.latency_samples);
        double emax = 0;
        for (std::size_t k = lat + 50; k < got; ++k)
            emax = std::max(emax, std::fabs(std::remainder(std::atan2(rs[k], rc[k]) - std::atan2(s[k - lat], c[k - lat]), 2 * kPi)));
        CHECK(emax < 0.05);
    }
    if (ReplayPort* rp = d->replay()) {  // a source: it carries truth, and the samples follow it
        const std::size_t n = 4000;
        std::vector<double> rs(n), rc(n), th(n), om(n);
        rp->start(100000.0);
        std::size_t got = 0;
        bool truth = false;
        while (got < n) {
            const auto r = rp->read(std::span(rs).subspan(got), std::span(rc).subspan(got), 1000);
            REQUIRE(r.status == StreamStatus::Ok);
            REQUIRE(r.dropped == 0);
            if (r.frames == 0) break;  // end of the capture
            truth = rp->last_truth(std::span(th).subspan(got, r.frames), std::span(om).subspan(got, r.frames));
            got += r.frames;
        }
        REQUIRE(got > 0);
        REQUIRE(truth);
        double amp2 = 0, emax = 0;
        for (std::size_t k = 0; k < got; ++k) {
            REQUIRE(std::isfinite(rs[k]));
            REQUIRE(std::isfinite(rc[k]));
            amp2 += rs[k] * rs[k] + rc[k] * rc[k];
            emax = std::max(emax, std::fabs(std::remainder(std::atan2(rs[k], rc[k]) - th[k], 2 * kPi)));
        }
        CHECK(std::sqrt(amp2 / static_cast<double>(got)) > 0.05);
        CHECK(emax < 0.1);  // within what any encoder's harmonics allow
    }
    if (StepPort* sp = d->step()) {
        // A circle of static pairs: the readback's angle (or the DUT's position) follows within 1e-3 rad.
        double emax = 0;
        for (int k = 0; k < 32; ++k) {
            const double th = 2 * kPi * k / 32.0;
            const auto r = sp->measure(0.8 * std::sin(th), 0.8 * std::cos(th), 0.002, 1);  // 2 ms: simulated filters settle
            const double got = r.dut_theta_rad ? *r.dut_theta_rad : std::atan2(r.sin_v, r.cos_v);
            emax = std::max(emax, std::fabs(std::remainder(got - th, 2 * kPi)));
            CHECK(std::hypot(r.sin_v, r.cos_v) == Approx(0.8).margin(0.01));
        }
        CHECK(emax < 1e-3);
    }
}

// ---- Instruments (scpi-* backends: a generator and a digitizer of fringe instrument-sim) ----
namespace {
std::string env(const char* k) {
    const char* v = std::getenv(k);
    return v ? v : "";
}
struct Pair {
    std::unique_ptr<Device> gen, dig_owned;
    Device* dig = nullptr;
};
Pair open_pair(const std::string& gen_uri, const std::string& dig_uri) {
    Pair p;
    p.gen = open(gen_uri);
    if (dig_uri.empty() || dig_uri == gen_uri) {
        p.dig = p.gen.get();
    } else {
        p.dig_owned = open(dig_uri);
        p.dig = p.dig_owned.get();
    }
    return p;
}
// 10 cycles of 125 samples at 125 kS/s (a Red Pitaya rate: 125 MHz / 1000).
constexpr double kFs = 125000.0;
void test_signal(std::vector<double>& s, std::vector<double>& c) {
    s.resize(1250);
    c.resize(1250);
    for (std::size_t k = 0; k < s.size(); ++k) {
        s[k] = 0.8 * std::sin(2 * kPi * static_cast<double>(k) / 125.0);
        c[k] = 0.8 * std::cos(2 * kPi * static_cast<double>(k) / 125.0) + 0.05;
    }
}
}  // namespace

TEST_CASE("conformance: an instrument pair delivers the played signal delayed and warped by the link", "[conformance]") {
    auto probe = open(uri());
    if (!probe->info().can_play) {
        SUCCEED("not a generator");
        return;
    }
    probe.reset();
    // The link instrument-sim was started with: delay_s clock_ppm gain offset_v.
    std::istringstream link(env("FRINGE_TEST_LINK"));
    double delay_s = 0, ppm = 0, gain = 1, offset_v = 0;
    link >> delay_s >> ppm >> gain >> offset_v;
    REQUIRE(link);
    auto p = open_pair(uri(), env("FRINGE_TEST_RECORD_URI"));
    const auto gi = p.gen->info(), di = p.dig->info();
    CHECK(gi.can_play);
    CHECK(gi.own_clock);
    CHECK(gi.max_play_samples > 0);
    REQUIRE(di.can_record);
    const std::size_t P = static_cast<std::size_t>(di.settings.at("pretrigger_samples").get<long long>());
    std::vector<double> s, c;
    test_signal(s, c);
    REQUIRE(p.gen->player());
    REQUIRE(p.dig->recorder());
    p.gen->player()->play(s, c, kFs, true);
    const std::size_t M = 4000;
    std::vector<double> rs(M), rc(M);
    const auto r = p.dig->recorder()->record(rs, rc, kFs, 10.0);
    p.gen->player()->stop_output();
    INFO(r.message);
    REQUIRE(r.status == StreamStatus::Ok);
    REQUIRE(r.frames == M);
    // Sample m lies (m - P)/fs after the generator's start (its sync triggers the digitizer);
    // it shows what the generator played delay_s before, on a clock ppm fast.
    double emax = 0;
    for (std::size_t m = 0; m < M; ++m) {
        const double u = ((static_cast<double>(m) - static_cast<double>(P)) / kFs - delay_s) * (1 + ppm * 1e-6) * kFs;
        const double es = gain * sim_interpolate(s, true, u) + offset_v, ec = gain * sim_interpolate(c, true, u) + offset_v;
        emax = std::max({emax, std::fabs(rs[m] - es), std::fabs(rc[m] - ec)});
    }
    CHECK(emax < 1e-3);  // converter quantisation only (16/14-bit DAC and ADC)
    // Before the output starts the input is idle (the link's offset only).
    CHECK(std::fabs(rs[P / 2] - offset_v) < 1e-3);
}

TEST_CASE("conformance: an instrument's own error (error queue) is named in the DeviceError", "[conformance]") {
    auto probe = open(uri());
    if (!probe->info().can_play) {
        SUCCEED("not a generator");
        return;
    }
    probe.reset();
    // The driver believes in more memory than the instrument has: the instrument refuses the
    // upload, and its SYST:ERR? text reaches the message.
    auto g = open(with_setting(uri(), "memory_samples=100000"));
    std::vector<double> s(20000, 0.1), c(20000, -0.1);
    s[1] = 0.2;
    c[1] = -0.2;
    try {
        g->player()->play(s, c, kFs, true);
        FAIL("an upload beyond the instrument's memory was accepted");
    } catch (const DeviceError& e) {
        INFO(e.what());
        CHECK_THAT(e.what(), Catch::Contains("instrument error after"));
        CHECK_THAT(e.what(), Catch::Contains(",\""));  // the native `-225,"Out of memory..."` entry
        CHECK(std::string(e.what()).find("-22") != std::string::npos);
    }
    // The error queue was drained: the next command works.
    std::vector<double> s2, c2;
    test_signal(s2, c2);
    CHECK_NOTHROW(g->player()->play(s2, c2, kFs, true));
    g->player()->stop_output();
}

TEST_CASE("conformance: a silent instrument is a timeout naming the command", "[conformance]") {
    const std::string silent = env("FRINGE_TEST_SILENT_URI");
    if (silent.empty()) {
        SUCCEED("no silent instrument for this backend");
        return;
    }
    auto g = open(with_setting(silent, "timeout_s=0.3"));  // it answers the opening commands, then falls silent
    std::vector<double> s, c;
    test_signal(s, c);
    const auto t0 = std::chrono::steady_clock::now();
    try {
        g->player()->play(s, c, kFs, true);
        FAIL("play on a silent instrument returned");
    } catch (const DeviceError& e) {
        INFO(e.what());
        CHECK_THAT(e.what(), Catch::Contains("timeout"));
        CHECK_THAT(e.what(), Catch::Contains("'"));  // the command it waited for, quoted
    }
    CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5));
}

TEST_CASE("conformance: an instrument gone mid-run is a clear error", "[conformance]") {
    const std::string gone = env("FRINGE_TEST_GONE_URI");
    if (gone.empty()) {
        SUCCEED("no instrument to kill for this backend");
        return;
    }
    auto g = open(with_setting(gone, "timeout_s=2"));
    std::vector<double> s, c;
    test_signal(s, c);
    g->player()->play(s, c, kFs, true);
    REQUIRE(::kill(static_cast<pid_t>(std::stol(env("FRINGE_TEST_GONE_PID"))), SIGKILL) == 0);
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    const auto t0 = std::chrono::steady_clock::now();
    try {
        g->player()->play(s, c, kFs, true);
        FAIL("play on a killed instrument returned");
    } catch (const DeviceError& e) {
        INFO(e.what());
        CHECK_THAT(e.what(), Catch::Contains("connection"));
    }
    CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5));
}
