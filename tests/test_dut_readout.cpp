// A DUT read out by a device of its own (a scenario's device.dut, drivers/readout.cpp): its
// words scored once each against the truth at their latch instants, its latency measured
// apart, its wire errors counted; the readout lost or frozen mid-run (docs/dut-readouts.md).
// Truth here is analytic: a constant electrical frequency f from t = 0 has theta(t) = 2 pi f t.
#include "drivers/position_words.hpp"
#include "helpers.hpp"
#include "server/engine/plan.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "sr_writer.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

using namespace fringe;
using nlohmann::json;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kFe = 150.0;  // electrical frequency, Hz
constexpr double kOmega = 2 * kPi * kFe;

double truth_rad(double t_s) { return kOmega * t_s; }

json scenario(const std::string& dut_uri, double duration_s = 0.3) {
    return {{"name", "dut-readout"},
            {"encoder", test::clean_ideal(1024)},
            {"motion", {{"kind", "constant"}, {"electrical_freq_hz", kFe}}},
            {"sample_rate_hz", 100000},
            {"duration_s", duration_s},
            {"seed", 11},
            {"settle_s", 0.02},
            {"device", {{"output", "loopback:"}, {"input", "loopback:"}, {"dut", dut_uri}}},
            {"estimators", json::array({json{{"name", "atan2"}}})}};
}

json run(const json& sc) { return json(execute_run(scenario_from_json(sc, ""))); }

const json& lane(const json& r, const std::string& label) {
    for (const auto& e : r["estimators"])
        if (e["label"] == label) return e;
    FAIL("no lane " << label);
    static json none;
    return none;
}

// A word of a DUT whose position is `latency_s` old at its latch, in M counts per electrical cycle.
std::uint64_t count_at(double t_latch_s, double latency_s, std::uint64_t M) {
    const double cyc = truth_rad(t_latch_s - latency_s) / (2 * kPi);
    return static_cast<std::uint64_t>(std::floor((cyc - std::floor(cyc)) * static_cast<double>(M))) % M;
}

std::string lines(double latency_s, std::uint64_t M, double t_end_s, int malformed_every) {
    std::string s;
    int k = 0;
    for (double t = 0.0005; t < t_end_s; t += 1e-4, ++k) {
        if (malformed_every > 0 && k % malformed_every == 3) s += "12x3 garbage\n";
        char b[64];
        std::snprintf(b, sizeof b, "%.9f %llu\n", t, static_cast<unsigned long long>(count_at(t, latency_s, M)));
        s += b;
    }
    return s;
}

// A TCP server on 127.0.0.1 that sends `text` (the first `cut` bytes, then, unless `hold`, closes;
// with hold it keeps the connection open and silent until told to stop).
struct LineServer {
    int fd = -1, port = 0;
    std::thread th;
    std::atomic<bool> stop{false};
    LineServer(std::string text, std::size_t cut, bool hold) {
        fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
        socklen_t len = sizeof a;
        ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
        port = ntohs(a.sin_port);
        REQUIRE(::listen(fd, 1) == 0);
        th = std::thread([this, text = std::move(text), cut, hold] {
            const int c = ::accept(fd, nullptr, nullptr);
            if (c < 0) return;
            std::size_t sent = 0;
            const std::size_t n = std::min(cut, text.size());
            while (sent < n) {
                const ssize_t w = ::send(c, text.data() + sent, std::min<std::size_t>(4096, n - sent), MSG_NOSIGNAL);
                if (w <= 0) break;
                sent += static_cast<std::size_t>(w);
            }
            while (hold && !stop) std::this_thread::sleep_for(std::chrono::milliseconds(10));
            ::close(c);
        });
    }
    ~LineServer() {
        stop = true;
        ::shutdown(fd, SHUT_RDWR);
        ::close(fd);
        if (th.joinable()) th.join();
    }
};

}  // namespace

TEST_CASE("a DUT's line stream is scored word by word at its latch instants, its latency measured apart", "[dut_readout]") {
    test::TempDir d;
    constexpr std::uint64_t M = 4096;
    const double step_rad = 2 * kPi / M;
    for (const double latency_s : {0.0, 50e-6, 230e-6}) {
        CAPTURE(latency_s);
        const std::string path = (d.path / "words.txt").string();
        std::ofstream(path) << lines(latency_s, M, 0.3, 1000);
        const json r = run(scenario("readout:" + path + "?counts_per_rev=4096"));
        REQUIRE(r["status"] == "done");
        const json& dut = lane(r, "dut");
        const json& m = dut["metrics"];
        // Every word after the settle time (from the first word) scored once, up to the last frame.
        int expect_words = 0;
        for (double t = 0.0005; t < 0.3; t += 1e-4) expect_words += t >= 0.0005 + 0.02 && t <= 0.3 - 1e-5;
        CHECK(m["evidence"]["scored_samples"].get<double>() == Approx(expect_words).margin(1));
        CHECK(m["slipped_samples"] == 0);
        // The error is the latency's -omega*tau plus the count's quantisation, uniform in a step.
        CHECK(m["mean"]["rad"].get<double>() == Approx(-kOmega * latency_s).margin(0.05 * step_rad));
        const double rms = m["rms"]["rad"].get<double>();
        const double expect = std::sqrt(kOmega * latency_s * kOmega * latency_s + step_rad * step_rad / 12);
        CHECK(rms == Approx(expect).epsilon(0.03));
        const json& ro = m["readout"];
        CHECK(ro["protocol"] == "lines");
        CHECK(ro["malformed_lines"] == 3);
        CHECK(ro["word_rate_hz"].get<double>() == Approx(10000).epsilon(1e-6));
        if (latency_s > 0) CHECK(ro["latency_s"].get<double>() == Approx(latency_s).epsilon(0.02));
        // Without its latency the DUT's error is its count's quantisation alone.
        CHECK(ro["rms_without_latency_rad"].get<double>() == Approx(step_rad / std::sqrt(12.0)).epsilon(0.05));
        bool warned = false;
        for (const auto& w : r["warnings"]) warned |= w["code"] == "dut_wire_errors";
        CHECK(warned);
        // The traces draw each word at its own instant: by true angle, every scored word once,
        // within half a step of -omega*tau; in time, the envelope within the same band.
        const json& tr = r["traces"];
        REQUIRE(tr.contains("by_angle"));
        const json& fold = tr["by_angle"]["error_rad"]["dut"];
        double folded = 0, lo = 1e9, hi = -1e9;
        for (std::size_t b = 0; b < fold["count"].size(); ++b) {
            const double c = fold["count"][b].get<double>();
            folded += c;
            if (c > 0) {
                lo = std::min(lo, fold["min"][b].get<double>());
                hi = std::max(hi, fold["max"][b].get<double>());
            }
        }
        CHECK(folded == Approx(m["evidence"]["scored_samples"].get<double>()).margin(6));  // the folds start 5 words (the first word at 0.5 ms) before the scoring
        CHECK(lo >= -kOmega * latency_s - 0.5 * step_rad - 1e-5);
        CHECK(hi <= -kOmega * latency_s + 0.5 * step_rad + 1e-5);
        CHECK(hi - lo > 0.9 * step_rad);  // the whole step, not a few points
        const json& env = tr["error_rad"]["dut"];
        std::size_t drawn = 0;
        for (std::size_t b = 0; b < env["min"].size(); ++b)
            if (env["min"][b].is_number()) {
                ++drawn;
                CHECK(env["min"][b].get<double>() >= -kOmega * latency_s - 0.5 * step_rad - 1e-5);
                CHECK(env["max"][b].get<double>() <= -kOmega * latency_s + 0.5 * step_rad + 1e-5);
            }
        CHECK(drawn > 0.9 * env["min"].size());
    }
}

TEST_CASE("limits name the DUT readout's wire errors and latency", "[dut_readout]") {
    test::TempDir d;
    const std::string path = (d.path / "words.txt").string();
    std::ofstream(path) << lines(100e-6, 4096, 0.3, 500);
    json sc = scenario("readout:" + path + "?counts_per_rev=4096");
    sc["limits"] = json::array({json{{"estimator", "dut"}, {"metric", "dut_wire_errors"}, {"max", 0}},
                                json{{"estimator", "dut"}, {"metric", "dut_latency_s"}, {"max", 80e-6}}});
    const json r = run(sc);
    REQUIRE(r["status"] == "done");
    CHECK(r["verdict"] == "FAIL");
    int failed = 0;
    for (const auto& ms : r["measurements"])
        if ((ms["metric"] == "dut_wire_errors" || ms["metric"] == "dut_latency_s") && ms["outcome"] == "FAIL") ++failed;
    CHECK(failed == 2);
}

TEST_CASE("a BiSS-C DUT recorded by a logic analyser: CRC errors counted and never scored", "[dut_readout]") {
    test::TempDir d;
    BissConfig c;
    c.position_bits = 14;
    c.angle.counts_per_rev = 1u << 14;
    const std::uint64_t M = c.angle.counts_per_rev;
    EmitterTiming tm;
    tm.sample_rate_hz = 4e6;
    tm.half_clock_samples = 2;
    tm.idle_samples = 100;  // longer than the 20 us timeout: the decoder sees the first frame start from idle
    const double latency_s = 40e-6, word_period_s = 100e-6, end_s = 0.25;
    LogicSignals sig;
    int frames = 0, flipped = 0;
    while (true) {
        const double start_s = static_cast<double>(sig.t_s.size()) / tm.sample_rate_hz;
        if (start_s + word_period_s > end_s) break;
        // Where this frame latches (it does not depend on the value), then the frame itself.
        LogicSignals probe = sig;
        const double latch_s = emit_biss_frame(c, tm, 0, {}, probe);
        WordFault f;
        if (frames % 37 == 5) {
            f.flip_bit = 1 + 1 + 1 + 14 + 2 + 3;  // Ack, Start, CDS, data, nE, nW, then a CRC bit
            ++flipped;
        }
        emit_biss_frame(c, tm, count_at(latch_s, latency_s, M), f, sig);
        ++frames;
        const auto want = static_cast<std::size_t>(std::llround((start_s + word_period_s) * tm.sample_rate_hz));
        if (want > sig.t_s.size()) emit_idle(tm, static_cast<int>(want - sig.t_s.size()), sig);
    }
    const std::string path = (d.path / "biss.sr").string();
    test::write_logic_sr(path, tm.sample_rate_hz, {"ma", "slo"}, {&sig.clk, &sig.data});
    const json r = run(scenario("readout:" + path + "?protocol=biss&position_bits=14", end_s));
    REQUIRE(r["status"] == "done");
    const json& m = lane(r, "dut")["metrics"];
    const json& ro = m["readout"];
    CHECK(ro["crc_errors"] == flipped);
    CHECK(ro["invalid_words"] == flipped);
    CHECK(ro["valid_words"] == frames - flipped);
    CHECK(m["slipped_samples"] == 0);
    CHECK(ro["latency_s"].get<double>() == Approx(latency_s).epsilon(0.02));
    CHECK(ro["rms_without_latency_rad"].get<double>() == Approx(2 * kPi / static_cast<double>(M) / std::sqrt(12.0)).epsilon(0.05));
    // Invalid words are counted, not scored: the valid fraction says how many.
    const double vf = m["evidence"]["valid_fraction"].get<double>();
    CHECK(vf < 1.0);
    CHECK(vf > 0.95);
    for (const auto& ms : r["measurements"])
        if (ms["metric"] == "dut_crc_errors") CHECK(ms["value"] == flipped);

    // The same session replayed through the live path (sigrok-cli -i, as an analyser's stream):
    // the same words, so the same figures to the last bit; the acquisition's own account.
    const json rl = run(scenario("readout:sigrok://" + path + "?protocol=biss&position_bits=14", end_s));
    REQUIRE(rl["status"] == "done");
    json a = m, b = lane(rl, "dut")["metrics"];
    const json live = b["readout"]["sigrok"];
    CHECK(live["input_file"] == path);
    CHECK(live["samples"] == sig.t_s.size());
    CHECK(live["limit_samples"] == sig.t_s.size());
    CHECK(live["exit_status"] == 0);
    b["readout"].erase("sigrok");
    CHECK(a.dump() == b.dump());
    // A rate that is not the file's is refused naming both.
    const json bad = run(scenario("readout:sigrok://" + path + "?protocol=biss&position_bits=14&logic_rate_hz=1000000", end_s));
    CHECK(bad["status"] == "error");
    CHECK_THAT(bad.value("error", std::string()), Catch::Contains("recorded at 4e+06 Hz") || Catch::Contains("recorded at 4000000 Hz"));
    // A relative session path is not taken for a driver's name.
    const json rel = run(scenario("readout:sigrok://./biss.sr?protocol=biss&position_bits=14", end_s));
    CHECK(rel["status"] == "error");
    CHECK_THAT(rel.value("error", std::string()), Catch::Contains("absolute path"));
}

TEST_CASE("a DUT's TCP stream that closes or freezes mid-run ends the run with an error naming it", "[dut_readout]") {
    const std::string text = lines(0.0, 4096, 0.3, 0);
    SECTION("the board closes the connection halfway") {
        LineServer srv(text, text.size() / 2, false);
        const json r = run(scenario("readout:tcp://127.0.0.1:" + std::to_string(srv.port) + "?counts_per_rev=4096"));
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("device.dut") && Catch::Contains("closed the connection"));
        // What came before is kept: the estimator's lane and the words read were scored.
        CHECK(lane(r, "atan2")["metrics"]["evidence"]["scored_samples"].get<double>() > 1000);
        CHECK(lane(r, "dut")["metrics"]["evidence"]["scored_samples"].get<double>() > 500);
    }
    SECTION("the board stops sending but keeps the connection") {
        LineServer srv(text, text.size() / 2, true);
        const auto t0 = std::chrono::steady_clock::now();
        const json r = run(scenario("readout:tcp://127.0.0.1:" + std::to_string(srv.port) + "?counts_per_rev=4096&stall_s=0.3"));
        const double took_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("device.dut") && Catch::Contains("timeout"));
        CHECK(took_s < 5);
    }
    SECTION("nobody listens") {
        LineServer srv(text, 0, false);
        const int port = srv.port;
        ::shutdown(srv.fd, SHUT_RDWR);
        ::close(srv.fd);
        srv.fd = -1;
        const json r = run(scenario("readout:tcp://127.0.0.1:" + std::to_string(port) + "?counts_per_rev=4096"));
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("device.dut") && Catch::Contains("cannot connect"));
    }
}

TEST_CASE("a DUT stream that never reaches the run's time ends the run, bounded in time", "[dut_readout]") {
    test::TempDir d;
    auto timed = [](const json& sc, double& took_s) {
        const auto t0 = std::chrono::steady_clock::now();
        const json r = run(sc);
        took_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        return r;
    };
    double took_s = 0;
    SECTION("a FIFO nobody writes to") {
        const std::string fifo = (d.path / "fifo").string();
        REQUIRE(::mkfifo(fifo.c_str(), 0600) == 0);
        const json r = timed(scenario("readout:" + fifo + "?counts_per_rev=4096&stall_s=0.3"), took_s);
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("device.dut"));
        CHECK(took_s < 5);
    }
    SECTION("a device that sends only zeros") {
        const json r = timed(scenario("readout:/dev/zero?counts_per_rev=4096&stall_s=0.3"), took_s);
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("device.dut") && Catch::Contains("timeout"));
        CHECK(took_s < 5);
    }
    SECTION("a directory") {
        const json r = timed(scenario("readout:" + d.path.string() + "?counts_per_rev=4096"), took_s);
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("is a directory"));
    }
    SECTION("a FIFO named as a session, to the file reader and to the replay") {
        const std::string fifo = (d.path / "fifo.sr").string();
        REQUIRE(::mkfifo(fifo.c_str(), 0600) == 0);
        for (const std::string via : {"readout:", "readout:sigrok://"}) {
            const json r = timed(scenario(via + fifo + "?protocol=ssi&position_bits=12"), took_s);
            CHECK(r["status"] == "error");
            CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("not a regular file"));
            CHECK(took_s < 5);
        }
        const json r = timed(scenario("readout:sigrok://" + (d.path / "missing.sr").string() + "?protocol=ssi&position_bits=12"), took_s);
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("No such file"));
    }
    SECTION("a session of 70 s of silence: its first 65.5 s are read for words, not all of it") {
        const std::vector<double> zeros(70 * 50000, 0.0);
        const std::string sr = (d.path / "quiet.sr").string();
        test::write_logic_sr(sr, 50000, {"clk", "data"}, {&zeros, &zeros});
        const json r = timed(scenario("readout:" + sr + "?protocol=ssi&position_bits=12"), took_s);
        CHECK(r["status"] == "error");
        const std::string e = r["error"].get<std::string>();
        CHECK_THAT(e, Catch::Contains("fewer than three words"));
        const auto at = e.find("logic_samples ");
        REQUIRE(at != std::string::npos);
        const double read = std::stod(e.substr(at + 14));
        CHECK(read < 67 * 50000.0);  // up to 65.5 s and the decode's hold and chunk
        CHECK(read >= 64 * 50000.0);
    }
}

TEST_CASE("DUT words that do not cover the run are said so, and a stream that covers it and stays open is not frozen", "[dut_readout]") {
    test::TempDir d;
    SECTION("a file that ends early: scored as far as it goes, and a warning") {
        const std::string path = (d.path / "words.txt").string();
        std::ofstream(path) << lines(0.0, 4096, 0.1, 0);
        const json r = run(scenario("readout:" + path + "?counts_per_rev=4096"));
        REQUIRE(r["status"] == "done");
        bool warned = false;
        for (const auto& w : r["warnings"]) warned |= w["code"] == "dut_words_end_early";
        CHECK(warned);
        CHECK(lane(r, "dut")["metrics"]["readout"]["last_word_s"].get<double>() < 0.1);
    }
    SECTION("words on another clock: none in the run, a warning naming clock_offset_s") {
        const std::string path = (d.path / "words.txt").string();
        std::ofstream(path) << lines(0.0, 4096, 0.3, 0);
        const json r = run(scenario("readout:" + path + "?counts_per_rev=4096&clock_offset_s=-5"));
        REQUIRE(r["status"] == "done");
        bool warned = false;
        for (const auto& w : r["warnings"]) warned |= w["code"] == "dut_words_outside_run" && w["message"].get<std::string>().find("clock_offset_s") != std::string::npos;
        CHECK(warned);
        CHECK(r["verdict"] != "PASS");
    }
    SECTION("a TCP stream that covers the run and keeps its connection open") {
        const std::string text = lines(0.0, 4096, 0.3, 0);
        LineServer srv(text, text.size(), true);
        const auto t0 = std::chrono::steady_clock::now();
        const json r = run(scenario("readout:tcp://127.0.0.1:" + std::to_string(srv.port) + "?counts_per_rev=4096&stall_s=0.5"));
        CHECK(r["status"] == "done");
        CHECK(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() < 5);
    }
    SECTION("a cancel reaches a readout that waits") {
        const std::string fifo = (d.path / "fifo").string();
        REQUIRE(::mkfifo(fifo.c_str(), 0600) == 0);
        std::atomic<bool> cancel{false};
        RunOptions o;
        o.cancel = &cancel;
        std::thread t([&] {
            std::this_thread::sleep_for(std::chrono::milliseconds(300));
            cancel = true;
        });
        const auto t0 = std::chrono::steady_clock::now();
        const json r = json(execute_run(scenario_from_json(scenario("readout:" + fifo + "?counts_per_rev=4096&stall_s=600"), ""), o));
        t.join();
        CHECK(r["status"] == "aborted");  // the user's cancel, not a device fault
        CHECK(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() < 5);
    }
}

TEST_CASE("a DUT readout's bad settings are refused naming them", "[dut_readout]") {
    test::TempDir d;
    // A session of two idle lines (1000 samples) under the names given.
    auto idle_session = [&](const char* name, double rate_hz, std::vector<std::string> names) {
        LogicSignals sig;
        emit_idle(EmitterTiming{}, 1000, sig);
        const std::string sr = (d.path / name).string();
        test::write_logic_sr(sr, rate_hz, names, {&sig.clk, &sig.data});
        return sr;
    };
    const std::string path = (d.path / "words.txt").string();
    std::ofstream(path) << lines(0.0, 4096, 0.3, 0);
    SECTION("device.dut must be a readout") {
        CHECK_THROWS_WITH(plan_run(scenario_from_json(scenario("loopback:"), "")), Catch::Contains("device.dut"));
    }
    SECTION("an unknown readout setting") {
        CHECK_THROWS_WITH(plan_run(scenario_from_json(scenario("readout:" + path + "?wordbits=3"), "")), Catch::Contains("wordbits"));
    }
    SECTION("a setting of another protocol") {
        const json r = run(scenario("readout:" + path + "?word_bits=16"));
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("word_bits") && Catch::Contains("lines"));
    }
    SECTION("a word rate the words do not come at (they come every 100 us)") {
        for (const char* q : {"1e-06", "9400", "10600"}) {
            const json r = run(scenario("readout:" + path + "?counts_per_rev=4096&word_rate_hz=" + q));
            CHECK(r["status"] == "error");
            CHECK_THAT(r["error"].get<std::string>(), Catch::Contains(std::string("word_rate_hz=") + q) && Catch::Contains("come at 10000 Hz"));
        }
        for (const char* q : {"9600", "10400"}) {  // within 5 %: taken as given
            const json r = run(scenario("readout:" + path + "?counts_per_rev=4096&word_rate_hz=" + q));
            CHECK(r["status"] == "done");
            CHECK(lane(r, "dut")["metrics"]["readout"]["word_rate_hz"].get<double>() == std::stod(q));
        }
    }
    SECTION("a session whose samplerate is negative, replayed") {
        const std::string sr = idle_session("neg.sr", -5e6, {"clk", "data"});
        const json r = run(scenario("readout:sigrok://" + sr + "?protocol=ssi&position_bits=12"));
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("is not a rate in [1 Hz, 10 GHz]"));
    }
    SECTION("an ABZ readout without Z") {
        const std::string sr = idle_session("ab.sr", EmitterTiming{}.sample_rate_hz, {"a", "b"});
        for (const std::string via : {"readout:", "readout:sigrok://"}) {
            const json r = run(scenario(via + sr + "?protocol=abz&interpolation=4&word_rate_hz=10000"));
            CHECK(r["status"] == "error");
            CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("needs its index line Z"));
        }
    }
    SECTION("a logic capture's missing channel") {
        const std::string sr = idle_session("x.sr", EmitterTiming{}.sample_rate_hz, {"clk", "dat"});
        const json r = run(scenario("readout:" + sr + "?protocol=ssi&position_bits=12&word_rate_hz=10000"));
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("data"));
    }
}
