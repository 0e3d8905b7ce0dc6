// Driver conformance (libiio's habit): the same tests against every driver that can run in
// CI, selected by FRINGE_TEST_URI (tests/conformance.sh sets up each backend: loopback,
// capture, modbus over TCP and over RTU against board-sim). Every device must describe
// itself, reject unknown settings by name, refuse what it cannot do loudly (an error, not
// silence), and carry a known signal through what it can do.
#include "drivers/device.hpp"
#include "signal_gen/config.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

using namespace fringe;
using namespace fringe::dev;

#ifdef FRINGE_WITH_USB_EMULATOR
#include "drivers/usb_emulator.hpp"
#endif

namespace {
constexpr double kPi = 3.14159265358979323846;
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
    CHECK((i.streaming || i.step_mode));
    CHECK(i.latency_samples >= 0);
    bool listed = false;
    for (const auto& drv : drivers()) listed |= uri().rfind(drv.scheme + ":", 0) == 0 && !drv.summary.empty();
    CHECK(listed);
}

TEST_CASE("conformance: unknown settings are errors naming the key", "[conformance]") {
    CHECK_THROWS_WITH(open(with_setting(uri(), "no_such_setting=1")), Catch::Contains("device.no_such_setting"));
}

TEST_CASE("conformance: what the device cannot do fails loudly", "[conformance]") {
    auto d = open(uri());
    const auto i = d->info();
    if (!i.step_mode) CHECK_THROWS_AS(d->step(0.1, 0.2, 0.0, 1), DeviceError);
    if (!i.streaming) {
        std::vector<double> s(8, 0.1), c(8, 0.2);
        CHECK(d->write(s, c).status == StreamStatus::Error);
        CHECK(d->read(s, c, 10).status == StreamStatus::Error);
    }
}

TEST_CASE("conformance: a known signal goes through", "[conformance]") {
    INFO(uri());
    auto d = open(uri());
    const auto i = d->info();
    if (i.streaming) {
        const std::size_t n = 4000;
        std::vector<double> s(n), c(n), rs(n), rc(n);
        for (std::size_t k = 0; k < n; ++k) {
            s[k] = 0.9 * std::sin(2 * kPi * static_cast<double>(k) / 200.0);
            c[k] = 0.9 * std::cos(2 * kPi * static_cast<double>(k) / 200.0);
        }
        d->start(100000.0);
        if (i.needs_output) {
            REQUIRE(d->write(s, c).status == StreamStatus::Ok);
            d->end_of_output();
        }
        std::size_t got = 0;
        bool truth = false;
        std::vector<double> th(n), om(n);
        while (got < n) {
            const auto r = d->read(std::span(rs).subspan(got), std::span(rc).subspan(got), 1000);
            REQUIRE(r.status == StreamStatus::Ok);
            REQUIRE(r.dropped == 0);
            if (r.frames == 0) break;  // end of a capture
            truth = d->last_truth(std::span(th).subspan(got, r.frames), std::span(om).subspan(got, r.frames));
            got += r.frames;
        }
        d->stop();
        REQUIRE(got > 0);
        double amp2 = 0;
        for (std::size_t k = 0; k < got; ++k) {
            REQUIRE(std::isfinite(rs[k]));
            REQUIRE(std::isfinite(rc[k]));
            amp2 += rs[k] * rs[k] + rc[k] * rc[k];
        }
        const double amp = std::sqrt(amp2 / static_cast<double>(got));
        CHECK(amp > 0.05);
        if (i.needs_output) {  // a loop: what was written comes back (after the declared latency)
            const std::size_t lat = static_cast<std::size_t>(i.latency_samples);
            double emax = 0;
            for (std::size_t k = lat + 50; k < got; ++k)
                emax = std::max(emax, std::fabs(std::remainder(std::atan2(rs[k], rc[k]) - std::atan2(s[k - lat], c[k - lat]), 2 * kPi)));
            CHECK(emax < 0.05);
        } else {  // a source: it also carries truth, and the samples follow it
            REQUIRE(truth);
            double emax = 0;
            for (std::size_t k = 0; k < got; ++k) emax = std::max(emax, std::fabs(std::remainder(std::atan2(rs[k], rc[k]) - th[k], 2 * kPi)));
            CHECK(emax < 0.1);  // within what any encoder's harmonics allow
        }
    }
    if (i.step_mode) {
        // A circle of static pairs: the readback's angle (or the DUT's position) follows within 1e-3 rad.
        double emax = 0;
        for (int k = 0; k < 32; ++k) {
            const double th = 2 * kPi * k / 32.0;
            const auto r = d->step(0.8 * std::sin(th), 0.8 * std::cos(th), 0.002, 1);  // 2 ms: simulated filters settle
            const double got = r.dut_theta_rad ? *r.dut_theta_rad : std::atan2(r.sin_v, r.cos_v);
            emax = std::max(emax, std::fabs(std::remainder(got - th, 2 * kPi)));
            CHECK(std::hypot(r.sin_v, r.cos_v) == Approx(0.8).margin(0.01));
        }
        CHECK(emax < 1e-3);
    }
}
