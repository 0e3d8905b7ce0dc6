// Devices by capability: every kind of device has exactly the ports docs/architecture.md
// ("Device capabilities") lists for it, each port it has works, and the run engine drives a
// device only through the ports it has (a step-only device is never asked to stream).
#include "board_sim_thread.hpp"
#include "helpers.hpp"

#include "drivers/capture_file.hpp"
#include "drivers/device.hpp"
#include "drivers/sim/instrument_sim.hpp"
#include "server/engine/frame_source.hpp"
#include "signal_gen/base/constants.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <fstream>
#include <map>
#include <mutex>
#include <regex>
#include <sstream>
#include <thread>
#include <tuple>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_devices_cpp {

using namespace fringe;
using namespace fringe::dev;
using json = nlohmann::json;

namespace {

std::string join(const std::vector<std::string>& v) {
    std::string s;
    for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
    return s;
}

// The ports a device has, asked of the device itself (not of its info).
std::vector<std::string> ports_of(Device& d) {
    std::vector<std::string> p;
    if (d.stream()) p.push_back("stream");
    if (d.step()) p.push_back("step");
    if (d.player()) p.push_back("play");
    if (d.recorder()) p.push_back("record");
    if (d.replay()) p.push_back("replay");
    if (d.readout()) p.push_back("readout");
    return p;
}

// docs/architecture.md's table of device kinds: its first column (a kind, in backticks) to
// its ports column (comma-separated), for the rows under "Device capabilities".
std::map<std::string, std::string> documented_ports() {
    std::ifstream f(std::string(FRINGE_SOURCE_DIR) + "/docs/architecture.md");
    std::stringstream ss;
    ss << f.rdbuf();
    const std::string text = ss.str();
    const auto at = text.find("## Device capabilities");
    REQUIRE(at != std::string::npos);
    std::map<std::string, std::string> out;
    std::istringstream lines(text.substr(at));
    std::string line;
    const std::regex row(R"(^\| `([^`]+)` \| [^|]* \| ([a-z, ]+) \|)");
    while (std::getline(lines, line)) {
        if (line.rfind("## ", 0) == 0 && line != "## Device capabilities") break;
        std::smatch m;
        if (std::regex_search(line, m, row)) out[m[1]] = m[2];
    }
    return out;
}

// Every port a device has does its work: a short pass through each.
void exercise(Device& d) {
    std::vector<double> s(256), c(256), rs(256), rc(256), th(256), om(256);
    for (std::size_t k = 0; k < s.size(); ++k) {
        s[k] = 0.5 * std::sin(kTwoPi * static_cast<double>(k) / 64.0);
        c[k] = 0.5 * std::cos(kTwoPi * static_cast<double>(k) / 64.0);
    }
    if (StreamPort* st = d.stream()) {
        st->start(1e5);
        REQUIRE(st->write(s, c).status == StreamStatus::Ok);
        st->end_of_output();
        const auto r = st->read(rs, rc, 1000);
        CHECK(r.status == StreamStatus::Ok);
        CHECK(r.frames > 0);
        st->stop();
    }
    if (StepPort* sp = d.step()) {
        const auto r = sp->measure(0.3, 0.4, 0.0, 1);
        CHECK(std::hypot(r.sin_v, r.cos_v) == Approx(0.5).margin(0.01));
    }
    if (PlayPort* pp = d.player()) {
        constexpr double fs = 125000;  // a rate every generator and digitizer has (125 MHz / 1000)
        pp->play(s, c, fs, true);
        if (RecordPort* rp = d.recorder()) {  // one instrument: it records what it plays
            const auto r = rp->record(rs, rc, fs, 5.0);
            CHECK(r.status == StreamStatus::Ok);
            CHECK(r.frames == rs.size());
        }
        pp->stop_output();
    }
    if (ReplayPort* rp = d.replay()) {
        rp->start(1e5);
        const auto r = rp->read(rs, rc, 1000);
        CHECK(r.status == StreamStatus::Ok);
        CHECK(r.frames > 0);
        CHECK(rp->last_truth(std::span(th).first(r.frames), std::span(om).first(r.frames)));
    }
    if (ReadoutPort* ro = d.readout()) {
        ro->start();
        std::vector<PositionWordOut> w;
        const auto r = ro->read_words(1.0, w, 1000);
        CHECK(r.status == StreamStatus::Ok);
        CHECK(r.frames == w.size());
        CHECK(!w.empty());
        ro->stop();
    }
}

void check_kind(const std::map<std::string, std::string>& doc, const std::string& kind, Device& d) {
    INFO("device kind " << kind << " (" << d.info().uri << ")");
    REQUIRE(doc.count(kind) == 1);
    const std::vector<std::string> has = ports_of(d);
    CHECK(join(has) == doc.at(kind));
    CHECK(d.info().ports() == has);  // the info reports the ports, nothing more
    exercise(d);
}

// instrument-sim in a thread on free ports; the URIs of its generator and digitizer.
struct InstrumentThread {
    InstrumentSimOptions o;
    std::atomic<bool> stop{false};
    std::thread t;
    std::mutex mu;
    std::condition_variable cv;
    std::string gen, dig, failure;
    InstrumentThread(const std::string& generator, const std::string& digitizer) {
        o.generator = generator;
        o.digitizer = digitizer;
        o.generator_port = o.digitizer_port = 0;
        o.stop = &stop;
        o.on_listening = [this](const std::string& role, const std::string& uri) {
            std::lock_guard<std::mutex> l(mu);
            (role == "generator" ? gen : dig) = uri;
            cv.notify_all();
        };
        t = std::thread([this] {
            try {
                run_instrument_sim(o);
            } catch (const std::exception& e) {
                std::lock_guard<std::mutex> l(mu);
                failure = e.what();
                gen = dig = "failed";
                cv.notify_all();
            }
        });
        std::unique_lock<std::mutex> l(mu);
        cv.wait_for(l, std::chrono::seconds(5), [&] { return !gen.empty() && !dig.empty(); });
    }
    ~InstrumentThread() {
        stop = true;
        if (t.joinable()) t.join();
    }
};

// A step-only device double that also carries stream methods as traps: the engine may reach
// them only through a StreamPort, which this device does not have.
class StepOnly final : public Device, public StepPort, public StreamPort {
public:
    StepPort* step() override { return this; }
    StepResult measure(double s, double c, double, int) override {
        ++steps;
        return {s, c, std::nullopt};
    }
    void start(double) override { ++stream_calls; }
    StreamResult write(std::span<const double> s, std::span<const double>) override { ++stream_calls; return {StreamStatus::Ok, s.size(), 0, 0, {}}; }
    StreamResult read(std::span<double>, std::span<double>, int) override { ++stream_calls; return {}; }
    void stop() override { ++stream_calls; }
    int steps = 0, stream_calls = 0;

protected:
    DeviceInfo describe() const override {
        DeviceInfo i;
        i.driver = "test-step";
        i.uri = "test-step:";
        i.board_id = "test";
        return i;
    }
};

// Both a stream and a step port (as the loopback): the engine streams, and never steps.
class StreamAndStep final : public Device, public StepPort, public StreamPort {
public:
    StepPort* step() override { return this; }
    StreamPort* stream() override { return this; }
    StepResult measure(double, double, double, int) override { ++steps; return {}; }
    void start(double) override {}
    StreamResult write(std::span<const double> s, std::span<const double> c) override {
        q_s.insert(q_s.end(), s.begin(), s.end());
        q_c.insert(q_c.end(), c.begin(), c.end());
        return {StreamStatus::Ok, s.size(), 0, 0, {}};
    }
    StreamResult read(std::span<double> s, std::span<double> c, int) override {
        const std::size_t n = std::min(s.size(), q_s.size() - pos);
        for (std::size_t i = 0; i < n; ++i, ++pos) { s[i] = q_s[pos]; c[i] = q_c[pos]; }
        reads += n;
        return {StreamStatus::Ok, n, 0, 0, {}};
    }
    void stop() override {}
    std::vector<double> q_s, q_c;
    std::size_t pos = 0, reads = 0;
    int steps = 0;

protected:
    DeviceInfo describe() const override {
        DeviceInfo i;
        i.driver = "test-both";
        i.uri = "test-both:";
        i.board_id = "test";
        return i;
    }
};

// No port at all, and half an instrument: nothing the engine can run through.
class NoPorts final : public Device {
protected:
    DeviceInfo describe() const override { DeviceInfo i; i.driver = "test-none"; i.uri = "test-none:"; return i; }
};
class GeneratorOnly final : public Device, public PlayPort {
public:
    PlayPort* player() override { return this; }
    void play(std::span<const double>, std::span<const double>, double, bool) override {}
    void stop_output() override {}
    std::size_t memory_samples() const override { return 0; }

protected:
    DeviceInfo describe() const override { DeviceInfo i; i.driver = "test-gen"; i.uri = "test-gen:"; return i; }
};

Scenario step_scenario() {
    Scenario sc;
    sc.name = "devices-test";
    sc.encoder = test::clean_ideal(1024);
    sc.motion = test::constant_electrical(100.0, 1024);
    sc.sample_rate_hz = 10000;
    sc.duration_s = 0.01;
    sc.device = "test:";
    sc.estimators = {{"atan2", "atan2", json::object(), std::nullopt}};
    return sc;
}

}  // namespace

TEST_CASE("devices: every kind has exactly the ports docs/architecture.md lists, and each works", "[device][capabilities]") {
    const auto doc = documented_ports();
    std::vector<std::string> checked;
    auto run = [&](const std::string& kind, Device& d) {
        check_kind(doc, kind, d);
        checked.push_back(kind);
    };
    {
        auto d = open("loopback:");
        run("loopback", *d);
    }
    {
        auto d = open("loopback:?own_clock=1");
        run("loopback own_clock", *d);
    }
    {
        test::TempDir dir;
        const std::string path = (dir.path / "c.fcap").string();
        {
            CaptureWriter w(path, {true, true, false}, json{{"sample_rate_hz", 1e5}, {"t0_s", 0.0}});
            CaptureData cd;
            for (int k = 0; k < 1000; ++k) {
                const double th = kTwoPi * k / 64.0;
                cd.t_s.push_back(k / 1e5);
                cd.sin_v.push_back(0.5 * std::sin(th));
                cd.cos_v.push_back(0.5 * std::cos(th));
                cd.theta_true_rad.push_back(th);
                cd.omega_true_rad_s.push_back(kTwoPi * 1e5 / 64.0);
            }
            w.write(cd);
        }
        auto d = open("capture:" + path);
        run("capture", *d);
    }
    {
        test::TempDir dir;
        const std::string path = (dir.path / "words.txt").string();
        {
            std::ofstream f(path);
            for (int k = 0; k < 100; ++k) f << k * 1e-3 << " " << (k * 37) % 4096 << "\n";
        }
        auto d = open("readout:" + path + "?counts_per_rev=4096");
        run("readout", *d);
    }
    {
        BoardSimOptions o;
        o.board = "generic-aio";
        test::SimThread sim(o);
        REQUIRE(sim.where.rfind("tcp://", 0) == 0);
        auto d = open(sim.uri("board=generic-aio&settle_s=0"));
        run("modbus", *d);
    }
    for (const auto& [kind, gen, dig] : {std::tuple<std::string, std::string, std::string>{"scpi generator", "keysight-33500b", "generic-scope"},
                                         {"scpi digitizer", "keysight-33500b", "generic-scope"},
                                         {"scpi generator and digitizer", "redpitaya", "redpitaya"}}) {
        InstrumentThread sim(gen, dig);
        INFO(sim.failure);
        REQUIRE(sim.gen.rfind("scpi", 0) == 0);
        auto d = open(kind == "scpi digitizer" ? sim.dig : sim.gen);
        // A digitizer alone records nothing without a generator: its port is checked, not run.
        if (kind == "scpi digitizer") {
            INFO(kind);
            REQUIRE(doc.count(kind) == 1);
            CHECK(join(ports_of(*d)) == doc.at(kind));
            CHECK(d->info().ports() == ports_of(*d));
            checked.push_back(kind);
        } else {
            run(kind, *d);
        }
    }
    // usb (stream) runs under umockdev's preload only: tests/test_usb.cpp checks its ports.
    checked.push_back("usb");
    std::vector<std::string> listed;
    for (const auto& [k, v] : doc) listed.push_back(k);
    std::sort(checked.begin(), checked.end());
    CHECK(join(checked) == join(listed));  // every documented kind is checked, and only those
}

TEST_CASE("devices: a step-only device is driven through its step port and never asked to stream", "[device][capabilities]") {
    const Scenario sc = step_scenario();
    StepOnly d;
    CHECK(d.info().ports() == std::vector<std::string>{"step"});
    auto src = make_frame_source(sc, d, d.info(), 64);
    Frames f;
    std::size_t got = 0;
    for (int i = 0; i < 100 && got < sc.samples(); ++i) {
        const auto st = src->next(64, f);
        REQUIRE(st.ok);
        got += f.size();
    }
    src->stop();
    CHECK(got == sc.samples());
    CHECK(d.steps == static_cast<int>(sc.samples()));
    CHECK(d.stream_calls == 0);
}

TEST_CASE("devices: a device with streams and steps is streamed, and one without a usable port is refused by name", "[device][capabilities]") {
    const Scenario sc = step_scenario();
    StreamAndStep both;
    {
        auto src = make_frame_source(sc, both, both.info(), 64);
        Frames f;
        REQUIRE(src->next(64, f).ok);
        CHECK(f.size() == 64);
        src->stop();
    }
    CHECK(both.reads == 64);
    CHECK(both.steps == 0);
    NoPorts none;
    CHECK(none.info().ports().empty());
    CHECK_THROWS_WITH(make_frame_source(sc, none, none.info(), 64), Catch::Contains("test-none:") && Catch::Contains("no port"));
    GeneratorOnly gen;
    CHECK(gen.info().ports() == std::vector<std::string>{"play"});
    CHECK_THROWS_WITH(make_frame_source(sc, gen, gen.info(), 64), Catch::Contains("generator without a digitizer"));
    // Instrument mode names the field whose device lacks its port.
    CHECK_THROWS_WITH(make_instrument_source(sc, gen, gen), Catch::Contains("device.input") && Catch::Contains("cannot record"));
    CHECK_THROWS_WITH(make_instrument_source(sc, none, gen), Catch::Contains("device.output") && Catch::Contains("cannot play"));
}

}  // namespace test_devices_cpp
