// Live acquisition through sigrok-cli (drivers/sigrok_live.hpp, docs/sigrok-live.md): against
// sigrok's demo driver (exact counts, channel mapping against the demo's documented patterns,
// continuous streaming, a killed and a frozen child) and fake sigrok-cli scripts (garbage, a
// short unit, an early or failed exit). Every acquisition is bounded by its timeouts and stop().
#include "drivers/device.hpp"
#include "drivers/sigrok_live.hpp"
#include "sr_writer.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <thread>
#include <vector>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_sigrok_live_cpp {

using namespace fringe;
namespace fs = std::filesystem;
using dev::SigrokLive;
using dev::SigrokLiveConfig;
using dev::StreamStatus;

namespace {

constexpr double kTwoPi = 6.283185307179586;

SigrokLiveConfig demo_logic(std::vector<std::string> channels, double rate_hz, std::uint64_t limit) {
    SigrokLiveConfig c;
    c.driver = "demo";
    c.samplerate_hz = rate_hz;
    c.logic_channels = std::move(channels);
    c.limit_samples = limit;
    return c;
}

struct Capture {
    std::vector<std::uint64_t> logic;
    std::vector<std::vector<double>> analog;
    dev::StreamResult last;
    std::size_t reads = 0;
};

// Reads until the end (Ok, 0 frames), an error or a timeout; checks that first_index counts on.
Capture read_all(SigrokLive& s, std::size_t analog_channels, int timeout_ms = 5000) {
    Capture cap;
    cap.analog.assign(analog_channels, {});
    std::vector<std::uint64_t> logic;
    std::vector<std::vector<double>> analog;
    while (true) {
        auto r = s.read(4096, logic, analog, timeout_ms);
        ++cap.reads;
        cap.last = r;
        if (r.status != StreamStatus::Ok || r.frames == 0) break;
        REQUIRE(r.first_index == (analog_channels ? cap.analog[0].size() : cap.logic.size()));
        cap.logic.insert(cap.logic.end(), logic.begin(), logic.end());
        for (std::size_t c = 0; c < analog_channels; ++c) {
            REQUIRE(analog[c].size() == r.frames);
            cap.analog[c].insert(cap.analog[c].end(), analog[c].begin(), analog[c].end());
        }
    }
    return cap;
}

bool reaped(pid_t pid) {
    // Not our child any more (waitpid: ECHILD) and gone (kill: ESRCH): reaped, no zombie left.
    errno = 0;
    const bool no_child = ::waitpid(pid, nullptr, WNOHANG) < 0 && errno == ECHILD;
    errno = 0;
    return no_child && ::kill(pid, 0) < 0 && errno == ESRCH;
}

std::size_t open_fds() {
    std::size_t n = 0;
    for ([[maybe_unused]] const auto& e : fs::directory_iterator("/proc/self/fd")) ++n;
    return n;
}

struct Dir {
    fs::path path;
    Dir() {
        path = fs::temp_directory_path() / ("fringe-srlive-" + std::to_string(getpid()) + "-" + std::to_string(std::random_device{}()));
        fs::create_directories(path);
    }
    ~Dir() {
        std::error_code ec;
        fs::remove_all(path, ec);
    }
    // A fake sigrok-cli: answers --scan like the real one (9 channels, D0..D8), else runs body.
    std::string script(const std::string& name, const std::string& body) const {
        const fs::path p = path / name;
        std::ofstream(p) << "#!/bin/sh\n"
                            "for a in \"$@\"; do [ \"$a\" = --scan ] && { echo 'fake - Fake device with 9 channels: D0 D1 D2 D3 D4 D5 D6 D7 D8'; exit 0; }; done\n"
                         << body << "\n";
        fs::permissions(p, fs::perms::owner_all);
        return p.string();
    }
};

SigrokLiveConfig fake(const std::string& program, std::vector<std::string> channels, std::uint64_t limit) {
    SigrokLiveConfig c;
    c.driver = "fake";
    c.program = program;
    c.samplerate_hz = 1000;
    c.logic_channels = std::move(channels);
    c.limit_samples = limit;
    return c;
}

}  // namespace

TEST_CASE("sigrok live: the demo driver delivers exactly limit_samples, then the end", "[sigrok_live]") {
    const std::size_t fds = open_fds();
    const std::uint64_t n = GENERATE(1, 4097, 100000);
    SigrokLive s(demo_logic({"D0", "D1", "D2"}, 1e6, n));
    s.start();
    const pid_t pid = s.pid();
    auto cap = read_all(s, 0);
    INFO(cap.last.message);
    REQUIRE(cap.last.status == StreamStatus::Ok);
    CHECK(cap.logic.size() == n);
    for (auto v : cap.logic) REQUIRE(v < 8);  // three channels: three bits
    const auto st = s.stats();
    CHECK(st.value("samples", 0u) == n);
    CHECK(st.value("bytes", 0u) == n);  // unit of one byte
    CHECK(st.value("exit_status", -1) == 0);
    CHECK(reaped(pid));
    // The end stays the end.
    std::vector<std::uint64_t> logic;
    std::vector<std::vector<double>> analog;
    auto again = s.read(10, logic, analog, 100);
    CHECK(again.status == StreamStatus::Ok);
    CHECK(again.frames == 0);
    s.stop();
    CHECK(open_fds() == fds);
}

TEST_CASE("sigrok live: logic bits follow the channels named, in their order (demo incremental pattern)", "[sigrok_live]") {
    // pattern=incremental (channel group Logic): sample i carries i mod 256 on D0..D7 (libsigrok
    // demo driver). sigrok-cli 0.7 applies -g to every --config, so the rate stays the demo's
    // default of 200 kHz.
    SigrokLiveConfig c = demo_logic({"D2", "D0", "D5"}, 200000, 1000);
    c.channel_group = "Logic";
    c.config = {{"pattern", "incremental"}};
    SigrokLive s(c);
    s.start();
    auto cap = read_all(s, 0);
    INFO(cap.last.message);
    REQUIRE(cap.last.status == StreamStatus::Ok);
    REQUIRE(cap.logic.size() == 1000);
    for (std::uint64_t i = 0; i < cap.logic.size(); ++i) {
        const std::uint64_t d = i % 256;
        const std::uint64_t want = ((d >> 2) & 1) | ((d & 1) << 1) | (((d >> 5) & 1) << 2);
        INFO("sample " << i);
        REQUIRE(cap.logic[i] == want);
    }
}

TEST_CASE("sigrok live: a subset of the demo's default pattern matches the full capture's bits", "[sigrok_live]") {
    // The default "sigrok" pattern is deterministic from the start of an acquisition: the bits
    // of D6, D1, D3 read on their own must be those bits of a capture of all eight channels.
    SigrokLive full(demo_logic({"D0", "D1", "D2", "D3", "D4", "D5", "D6", "D7"}, 1e6, 5000));
    full.start();
    auto all = read_all(full, 0);
    REQUIRE(all.last.status == StreamStatus::Ok);
    REQUIRE(all.logic.size() == 5000);
    SigrokLive sub(demo_logic({"D6", "D1", "D3"}, 1e6, 5000));
    sub.start();
    auto part = read_all(sub, 0);
    REQUIRE(part.last.status == StreamStatus::Ok);
    REQUIRE(part.logic.size() == 5000);
    std::size_t ones = 0;
    for (std::size_t i = 0; i < 5000; ++i) {
        const std::uint64_t a = all.logic[i];
        const std::uint64_t want = ((a >> 6) & 1) | (((a >> 1) & 1) << 1) | (((a >> 3) & 1) << 2);
        INFO("sample " << i);
        REQUIRE(part.logic[i] == want);
        ones += static_cast<std::size_t>(__builtin_popcountll(want));
    }
    CHECK(ones > 0);  // the pattern is not all-low
    CHECK(ones < 3 * 5000);
}

TEST_CASE("sigrok live: continuous acquisition streams until stop(), which reaps the child", "[sigrok_live]") {
    const std::size_t fds = open_fds();
    SigrokLive s(demo_logic({"D0", "D1"}, 1e6, 0));
    s.start();
    const pid_t pid = s.pid();
    std::vector<std::uint64_t> logic;
    std::vector<std::vector<double>> analog;
    std::uint64_t got = 0;
    const auto t0 = std::chrono::steady_clock::now();
    while (std::chrono::steady_clock::now() - t0 < std::chrono::milliseconds(400)) {
        auto r = s.read(1 << 16, logic, analog, 2000);
        INFO(r.message);
        REQUIRE(r.status == StreamStatus::Ok);
        REQUIRE(r.frames > 0);  // continuous: never the end
        REQUIRE(r.first_index == got);
        got += r.frames;
    }
    CHECK(got > 0);
    s.stop();
    CHECK(reaped(pid));
    const auto st = s.stats();
    CHECK(st.value("running", true) == false);
    CHECK(st.value("samples", 0u) == got);
    CHECK(st.value("expected_samples_by_wall_clock", 0.0) > 0);
    auto after = s.read(10, logic, analog, 100);
    CHECK(after.status == StreamStatus::Error);
    s.stop();  // idempotent
    CHECK(open_fds() == fds);
}

TEST_CASE("sigrok live: the child killed mid-run is an error naming the signal", "[sigrok_live]") {
    SigrokLive s(demo_logic({"D0"}, 1e6, 0));
    s.start();
    std::vector<std::uint64_t> logic;
    std::vector<std::vector<double>> analog;
    auto r = s.read(1000, logic, analog, 2000);
    REQUIRE(r.status == StreamStatus::Ok);
    REQUIRE(::kill(s.pid(), SIGKILL) == 0);
    for (int i = 0; i < 10000 && r.status == StreamStatus::Ok; ++i) r = s.read(1 << 16, logic, analog, 2000);
    REQUIRE(r.status == StreamStatus::Error);
    CHECK_THAT(r.message, Catch::Contains("sigrok:demo") && Catch::Contains("killed by signal 9"));
    CHECK(s.stats().value("exit_signal", 0) == SIGKILL);
    s.stop();
}

TEST_CASE("sigrok live: a frozen child is a timeout within the timeout, and stop() still cleans up", "[sigrok_live]") {
    SigrokLive s(demo_logic({"D0"}, 1e6, 0));
    s.start();
    const pid_t pid = s.pid();
    std::vector<std::uint64_t> logic;
    std::vector<std::vector<double>> analog;
    REQUIRE(s.read(1000, logic, analog, 2000).status == StreamStatus::Ok);
    REQUIRE(::kill(pid, SIGSTOP) == 0);
    // What the pipe already holds drains first; then nothing comes.
    dev::StreamResult r;
    std::chrono::steady_clock::duration last{};
    for (int i = 0; i < 100000; ++i) {
        const auto t0 = std::chrono::steady_clock::now();
        r = s.read(1 << 16, logic, analog, 300);
        last = std::chrono::steady_clock::now() - t0;
        if (r.status != StreamStatus::Ok) break;
    }
    INFO(r.message);
    REQUIRE(r.status == StreamStatus::Timeout);
    CHECK(last >= std::chrono::milliseconds(300));
    CHECK(last < std::chrono::milliseconds(3000));
    s.stop();
    CHECK(reaped(pid));
    CHECK(s.stats().contains("exit"));
}

TEST_CASE("sigrok live: the demo's analog channels stream as values (sine on A1)", "[sigrok_live]") {
    // The demo's A1 is a sine of amplitude 10 V and 20 samples per period (libsigrok demo
    // driver); -O analog prints 4-5 significant digits.
    SigrokLiveConfig c;
    c.driver = "demo";
    c.samplerate_hz = 100000;
    c.analog_channels = {"A1", "A0"};
    c.limit_samples = 2000;
    SigrokLive s(c);
    s.start();
    auto cap = read_all(s, 2);
    INFO(cap.last.message);
    REQUIRE(cap.last.status == StreamStatus::Ok);
    REQUIRE(cap.analog[0].size() == 2000);
    REQUIRE(cap.analog[1].size() == 2000);
    for (std::size_t i = 0; i < 2000; ++i) {
        INFO("sample " << i);
        REQUIRE(std::fabs(cap.analog[0][i] - 10 * std::sin(kTwoPi * static_cast<double>(i % 20) / 20)) < 1e-3);
        REQUIRE(std::fabs(std::fabs(cap.analog[1][i]) - 10) < 1e-3);  // A0: a +-10 V square
    }
}

TEST_CASE("sigrok live: configuration and device errors are clear and do not hang", "[sigrok_live]") {
    auto cause = [](SigrokLiveConfig c) -> std::string {
        try {
            SigrokLive s(std::move(c));
            s.start();
        } catch (const dev::DeviceError& e) {
            return e.what();
        }
        return "(no error)";
    };
    SECTION("an unknown driver: sigrok-cli's own message") {
        auto c = demo_logic({"D0"}, 1e6, 10);
        c.driver = "nosuchdriver";
        CHECK_THAT(cause(c), Catch::Contains("sigrok:nosuchdriver") && Catch::Contains("Driver nosuchdriver not found"));
    }
    SECTION("a channel the device does not have") {
        CHECK_THAT(cause(demo_logic({"D0", "D9"}, 1e6, 10)), Catch::Contains("sigrok:demo") && Catch::Contains("no channel 'D9'") && Catch::Contains("D7"));
    }
    SECTION("a program that does not exist") {
        auto c = demo_logic({"D0"}, 1e6, 10);
        c.program = "/nonexistent/sigrok-cli";
        CHECK_THAT(cause(c), Catch::Contains("sigrok:demo") && Catch::Contains("cannot run '/nonexistent/sigrok-cli'") && Catch::Contains("No such file"));
    }
    SECTION("no sample rate, no channels, both kinds, a channel twice") {
        CHECK_THAT(cause(demo_logic({"D0"}, 0, 10)), Catch::Contains("samplerate must be > 0"));
        CHECK_THAT(cause(demo_logic({}, 1e6, 10)), Catch::Contains("no channels"));
        CHECK_THAT(cause(demo_logic({"D0", "D0"}, 1e6, 10)), Catch::Contains("'D0' named twice"));
        auto c = demo_logic({"D0"}, 1e6, 10);
        c.analog_channels = {"A0"};
        CHECK_THAT(cause(c), Catch::Contains("logic and analog"));
    }
    SECTION("a device option sigrok-cli refuses") {
        auto c = demo_logic({"D0"}, 1e6, 10);
        c.config = {{"nosuchoption", "1"}};
        SigrokLive s(c);
        s.start();
        auto cap = read_all(s, 0);
        CHECK(cap.last.status == StreamStatus::Error);
        CHECK_THAT(cap.last.message, Catch::Contains("sigrok:demo") && Catch::Contains("exited with status"));
    }
}

TEST_CASE("sigrok live: hostile sigrok-cli output (fake program)", "[sigrok_live]") {
    Dir d;
    SECTION("a short last unit") {
        // D8: two-byte units; three bytes are one sample and half of another.
        SigrokLive s(fake(d.script("short", "printf '\\001\\001\\002'"), {"D8", "D0"}, 0));
        s.start();
        auto cap = read_all(s, 0);
        REQUIRE(cap.logic.size() == 1);
        CHECK(cap.logic[0] == 0b11);  // D8 (bit 8 of the unit) -> bit 0, D0 -> bit 1
        CHECK(cap.last.status == StreamStatus::Error);
        CHECK_THAT(cap.last.message, Catch::Contains("1 trailing bytes of an incomplete sample"));
    }
    SECTION("an early end: fewer samples than the limit") {
        SigrokLive s(fake(d.script("early", "printf 'abcd'"), {"D0"}, 10));
        s.start();
        auto cap = read_all(s, 0);
        CHECK(cap.logic.size() == 4);
        CHECK(cap.last.status == StreamStatus::Error);
        CHECK_THAT(cap.last.message, Catch::Contains("after 4 of 10 samples"));
    }
    SECTION("more samples than the limit") {
        SigrokLive s(fake(d.script("more", "printf 'abcdef'"), {"D0"}, 3));
        s.start();
        auto cap = read_all(s, 0);
        CHECK(cap.last.status == StreamStatus::Error);
        CHECK_THAT(cap.last.message, Catch::Contains("more than the 3 asked for"));
    }
    SECTION("a failed exit names the status and stderr") {
        SigrokLive s(fake(d.script("fail", "printf 'ab'; echo 'boom: device gone' >&2; exit 3"), {"D0"}, 0));
        s.start();
        auto cap = read_all(s, 0);
        CHECK(cap.logic.size() == 2);
        CHECK(cap.last.status == StreamStatus::Error);
        CHECK_THAT(cap.last.message, Catch::Contains("exited with status 3") && Catch::Contains("boom: device gone"));
        CHECK_THAT(s.stats().value("stderr_tail", std::string()), Catch::Contains("boom"));
    }
    SECTION("analog garbage") {
        auto c = fake(d.script("garbage", "echo 'D1: 1.0 V DC'; echo 'this is not sigrok'"), {}, 0);
        c.analog_channels = {"D1"};
        SigrokLive s(c);
        s.start();
        auto cap = read_all(s, 1);
        CHECK(cap.last.status == StreamStatus::Error);
        CHECK_THAT(cap.last.message, Catch::Contains("unparsable") && Catch::Contains("this is not sigrok"));
    }
    SECTION("analog values with SI prefixes, in base units") {
        auto c = fake(d.script("prefix", "printf 'D1: 250 mV DC\\nD2: 3.5 V\\nD1: -12 \\302\\265V\\nD2: 2 kV\\n'"), {}, 2);
        c.analog_channels = {"D1", "D2"};
        SigrokLive s(c);
        s.start();
        auto cap = read_all(s, 2);
        REQUIRE(cap.last.status == StreamStatus::Ok);
        REQUIRE(cap.analog[0].size() == 2);
        CHECK(cap.analog[0][0] == Approx(0.25));
        CHECK(cap.analog[0][1] == Approx(-12e-6));
        CHECK(cap.analog[1][0] == Approx(3.5));
        CHECK(cap.analog[1][1] == Approx(2000));
    }
    SECTION("a continuous acquisition that ends by itself is an error, not the end") {
        SigrokLive s(fake(d.script("quits", "printf 'abc'"), {"D0"}, 0));
        s.start();
        auto cap = read_all(s, 0);
        CHECK(cap.logic.size() == 3);
        CHECK(cap.last.status == StreamStatus::Error);
        CHECK_THAT(cap.last.message, Catch::Contains("continuous acquisition ended by itself after 3 samples") && Catch::Contains("exited with status 0"));
    }
    SECTION("a child that writes nothing and never exits: timeouts, then stop() ends it") {
        SigrokLive s(fake(d.script("silent", "exec sleep 60"), {"D0"}, 0));
        s.start();
        const pid_t pid = s.pid();
        std::vector<std::uint64_t> logic;
        std::vector<std::vector<double>> analog;
        CHECK(s.read(10, logic, analog, 200).status == StreamStatus::Timeout);
        s.stop();
        CHECK(reaped(pid));
    }
}

TEST_CASE("sigrok live: the sigrok: device records the demo's analog channels as sin and cos", "[sigrok_live]") {
    auto d = dev::open("sigrok:demo?samplerate=100000&sin=A1&cos=A0");
    const auto info = d->info();
    CHECK(info.driver == "sigrok");
    CHECK(info.can_record);
    CHECK(info.own_clock);
    REQUIRE(d->recorder());
    std::vector<double> sin_v(600), cos_v(600);
    auto r = d->recorder()->record(sin_v, cos_v, 50000, 10.0);
    INFO(r.message);
    REQUIRE(r.status == StreamStatus::Ok);
    REQUIRE(r.frames == 600);
    for (std::size_t i = 0; i < 600; ++i) {
        INFO("sample " << i);
        REQUIRE(std::fabs(sin_v[i] - 10 * std::sin(kTwoPi * static_cast<double>(i % 20) / 20)) < 1e-3);
        REQUIRE(std::fabs(std::fabs(cos_v[i]) - 10) < 1e-3);
    }
    // The URI's rate, not the run's, is what was asked of the device.
    const auto last = d->info().settings.value("last_record", nlohmann::json::object());
    CHECK(last.value("samplerate_hz", 0.0) == 100000.0);
    CHECK(last.value("samples", 0u) == 600u);
    CHECK_THROWS_WITH(dev::open("sigrok:demo?sin=A9"), Catch::Contains("no channel 'A9'"));
    CHECK_THROWS_WITH(dev::open("sigrok:nosuchdriver"), Catch::Contains("Driver nosuchdriver not found"));
    CHECK_THROWS_WITH(dev::open("sigrok:"), Catch::Contains("needs a driver"));
    // A URI names no executable (it may come over HTTP): an unknown setting.
    CHECK_THROWS_WITH(dev::open("sigrok:demo?program=/bin/sh"), Catch::Contains("program"));
}

}  // namespace test_sigrok_live_cpp

namespace test_sigrok_live_cpp {

TEST_CASE("sigrok live: a recorded session replayed (sigrok-cli -i) gives its samples, the channels named in their order", "[sigrok_live]") {
    Dir d;
    const std::size_t n = 30011;
    std::mt19937 rng(7);
    std::vector<std::vector<double>> lines(5, std::vector<double>(n));
    for (auto& l : lines)
        for (auto& v : l) v = static_cast<double>(rng() & 1u);
    const std::string sr = (d.path / "rec.sr").string();
    test::write_logic_sr(sr, 250000, {"p0", "p1", "p2", "p3", "p4"}, {&lines[0], &lines[1], &lines[2], &lines[3], &lines[4]});
    SigrokLiveConfig c;
    c.input_file = sr;
    c.logic_channels = {"p3", "p0", "p4"};
    SigrokLive s(c);
    s.start();
    CHECK(s.samplerate_hz() == 250000);  // the file's own
    const Capture cap = read_all(s, 0);
    REQUIRE(cap.last.status == StreamStatus::Ok);
    REQUIRE(cap.logic.size() == n);
    std::size_t wrong = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const std::uint64_t want = static_cast<std::uint64_t>(lines[3][i]) | static_cast<std::uint64_t>(lines[0][i]) << 1 |
                                   static_cast<std::uint64_t>(lines[4][i]) << 2;
        wrong += cap.logic[i] != want;
    }
    CHECK(wrong == 0);
    const auto st = s.stats();
    CHECK(st["limit_samples"] == n);
    CHECK(st["input_file"] == sr);
    CHECK(st["exit_status"] == 0);

    SECTION("a rate, a channel or a file that is not the session's is refused naming it") {
        SigrokLiveConfig b = c;
        b.samplerate_hz = 1e6;
        CHECK_THROWS_WITH(SigrokLive(b).start(), Catch::Contains("recorded at 250000 Hz, not the 1000000 Hz"));
        b = c;
        b.logic_channels = {"p9"};
        CHECK_THROWS_WITH(SigrokLive(b).start(), Catch::Contains("no channel 'p9'") && Catch::Contains("p0 p1 p2 p3 p4"));
        b = c;
        b.input_file = (d.path / "missing.sr").string();
        CHECK_THROWS_WITH(SigrokLive(b).start(), Catch::Contains("missing.sr") && Catch::Contains("No such file"));
        b.input_file = (d.path / "text.sr").string();
        std::ofstream(b.input_file) << "not a session\n";
        CHECK_THROWS_WITH(SigrokLive(b).start(), Catch::Contains("text.sr"));
        b = c;
        b.driver = "demo";
        CHECK_THROWS_WITH(SigrokLive(b), Catch::Contains("one source"));
        b = c;
        b.analog_channels = {"A0"};
        b.logic_channels.clear();
        CHECK_THROWS_WITH(SigrokLive(b), Catch::Contains("logic only"));
    }
    SECTION("a replay that ends short of the count the file declares is an error, not the end") {
        SigrokLiveConfig b = c;
        b.program = d.script("short", "case \"$*\" in *--show*) printf 'Samplerate: 1000\\nChannels: 5\\n- p0: logic\\n- p1: logic\\n- p2: logic\\n"
                                      "- p3: logic\\n- p4: logic\\nLogic unitsize: 1\\nLogic sample count: 10\\n'; exit 0;; esac\nprintf 'abc'; exit 0");
        SigrokLive f(b);
        f.start();
        const Capture fc = read_all(f, 0);
        CHECK(fc.logic.size() == 3);
        CHECK(fc.last.status == StreamStatus::Error);
        CHECK_THAT(fc.last.message, Catch::Contains("ended after 3 of 10 samples"));
    }
}

}  // namespace test_sigrok_live_cpp
