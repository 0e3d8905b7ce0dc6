// Truth alignment across clocks (issue 14): the estimator against analytic truth, the own-clock
// loopback, runs through output and input instruments, and the alignment measurements.
#include "helpers.hpp"

#include "drivers/device.hpp"
#include "server/analysis/align.hpp"
#include "server/engine/limits.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/http/service.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/fastmath.hpp"

#include <catch2/catch.hpp>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <limits>
#include <random>
#include <thread>
#include <unistd.h>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_align_cpp {

using namespace fringe;
using nlohmann::json;

namespace {

std::string fixture(const std::string& name) { return std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/" + name; }

// A played pair and its record computed from the same closed form x(t): the record at the
// warped, delayed times directly (no interpolator on the truth side).
struct Link {
    double delay_s = 0, ppm = 0, gs = 1, os = 0, gc = 1, oc = 0, noise_v = 0;
    bool cyclic = false;
};
struct Pair {
    std::vector<double> ps, pc, rs, rc;
};

Pair make_pair(const std::function<double(double)>& phase_rad, double fs, std::size_t n_play, std::size_t n_rec, const Link& l, std::uint64_t seed = 7) {
    Pair p;
    p.ps.resize(n_play);
    p.pc.resize(n_play);
    for (std::size_t i = 0; i < n_play; ++i) {
        const double th = phase_rad(static_cast<double>(i) / fs);
        p.ps[i] = 0.5 * std::sin(th);
        p.pc[i] = 0.5 * std::cos(th);
    }
    const double T = static_cast<double>(n_play) / fs;  // block period (cyclic)
    Xoshiro256pp rng(seed);
    p.rs.resize(n_rec);
    p.rc.resize(n_rec);
    for (std::size_t m = 0; m < n_rec; ++m) {
        double t = (static_cast<double>(m) / fs - l.delay_s) * (1 + l.ppm * 1e-6);  // generator time
        double s = 0, c = 0;
        const bool on = t >= 0 && (l.cyclic || t <= (static_cast<double>(n_play) - 1) / fs);
        if (on) {
            if (l.cyclic) t = std::fmod(t, T);
            const double th = phase_rad(t);
            s = 0.5 * std::sin(th);
            c = 0.5 * std::cos(th);
        }
        p.rs[m] = l.gs * s + l.os + l.noise_v * standard_normal(rng);
        p.rc[m] = l.gc * c + l.oc + l.noise_v * standard_normal(rng);
    }
    return p;
}

AlignResult run_align(const Pair& p, double fs, bool cyclic) {
    AlignInput in;
    in.played_sin_v = p.ps;
    in.played_cos_v = p.pc;
    in.play_rate_hz = fs;
    in.cyclic = cyclic;
    in.recorded_sin_v = p.rs;
    in.recorded_cos_v = p.rc;
    in.record_rate_hz = fs;
    return align(in);
}

Scenario small_run(const std::string& device) {
    Scenario sc;
    sc.name = "align-test";
    sc.encoder = test::clean_ideal(1024);
    sc.encoder.noise.sigma_add_v = 2e-4;
    sc.motion = test::constant_electrical(1234.5, 1024);
    sc.sample_rate_hz = 100000;
    sc.duration_s = 0.2;
    sc.settle_s = 0.02;
    sc.device = device;
    sc.estimators = {{"atan2", "atan2", json::object(), std::nullopt}};
    return sc;
}

}  // namespace

TEST_CASE("align: the interpolator reproduces band-limited signals", "[align]") {
    const double fs = 1000;
    for (double spc : {4.0, 8.0, 20.0, 100.0}) {
        std::vector<double> x(4000);
        const double w = kTwoPi * fs / spc;
        for (std::size_t i = 0; i < x.size(); ++i) x[i] = std::sin(w * static_cast<double>(i) / fs + 0.3);
        double worst = 0;
        for (double t = 1.0; t < 3.0; t += 0.0137) worst = std::max(worst, std::fabs(played_value(x, fs, false, t) - std::sin(w * t + 0.3)));
        INFO("samples per cycle " << spc);
        CHECK(worst < (spc < 5 ? 2e-3 : 2e-5));
    }
}

TEST_CASE("align: delay, clock offset, gain and offset against analytic truth", "[align]") {
    const double fs = 100000;
    Link l;
    l.delay_s = 1.23456e-3;  // 123.456 samples
    l.ppm = 37.5;
    l.gs = 0.91; l.os = 0.012; l.gc = 0.94; l.oc = -0.021;
    l.noise_v = 1e-4;
    SECTION("constant speed: a periodic signal, resolved by the onset") {
        const double f = 1234.5;
        const auto p = make_pair([&](double t) { return kTwoPi * f * t + 0.4; }, fs, 20000, 21000, l);
        const auto r = run_align(p, fs, false);
        INFO(r.error);
        REQUIRE(r.ok);
        CHECK(std::fabs(r.delay_s - l.delay_s) * fs < 2e-3);  // samples
        CHECK(std::fabs(r.clock_offset_ppm - l.ppm) < 0.05);
        CHECK(std::fabs(r.sin.gain / l.gs - 1) < 1e-4);
        CHECK(std::fabs(r.cos.gain / l.gc - 1) < 1e-4);
        CHECK(std::fabs(r.sin.offset_v - l.os) < 1e-5);
        CHECK(std::fabs(r.cos.offset_v - l.oc) < 1e-5);
        CHECK(r.residual_rms_v == Approx(1e-4).epsilon(0.05));  // the added noise, nothing else
        CHECK(r.ambiguity_z > 10);
        CHECK(r.candidates > 1);  // neighbouring periods were considered and rejected
    }
    SECTION("a chirp (no period), the record starting after the output") {
        l.delay_s = -0.8e-3;
        l.ppm = -120;
        const auto p = make_pair([&](double t) { return kTwoPi * (300 * t + 6000 * t * t); }, fs, 20000, 20000, l);
        const auto r = run_align(p, fs, false);
        INFO(r.error);
        REQUIRE(r.ok);
        CHECK(std::fabs(r.delay_s - l.delay_s) * fs < 2e-3);
        CHECK(std::fabs(r.clock_offset_ppm - l.ppm) < 0.05);
        CHECK(std::fabs(r.sin.gain / l.gs - 1) < 1e-4);
    }
    SECTION("cyclic playback of whole cycles, the record starting first") {
        l.cyclic = true;
        const double f = 1000.0;  // 100 samples a cycle: 20 cycles in the 2000-sample block
        const auto p = make_pair([&](double t) { return kTwoPi * f * t; }, fs, 2000, 30000, l);
        const auto r = run_align(p, fs, true);
        INFO(r.error);
        REQUIRE(r.ok);
        CHECK(std::fabs(r.delay_s - l.delay_s) * fs < 2e-3);
        CHECK(std::fabs(r.clock_offset_ppm - l.ppm) < 0.05);
    }
}

TEST_CASE("align: what cannot be aligned is refused, naming why", "[align]") {
    const double fs = 100000;
    Link l;
    l.delay_s = 0.5e-3;
    l.noise_v = 1e-4;
    auto sine = [](double t) { return kTwoPi * 1234.5 * t; };
    SECTION("a periodic signal whose onset is not in the record") {
        l.cyclic = true;
        l.delay_s = -3e-3;  // the record starts 3 ms after the output: every period looks alike
        const auto p = make_pair([](double t) { return kTwoPi * 1000.0 * t; }, fs, 2000, 30000, l);
        const auto r = run_align(p, fs, true);
        CHECK_FALSE(r.ok);
        CHECK_THAT(r.error, Catch::Contains("ambiguous delay") && Catch::Contains("record must start before the output"));
    }
    SECTION("noise only") {
        l.gs = l.gc = 0;
        const auto p = make_pair(sine, fs, 20000, 21000, l);
        const auto r = run_align(p, fs, false);
        CHECK_FALSE(r.ok);
        CHECK_THAT(r.error, Catch::Contains("no correlation"));
    }
    SECTION("sin and cos swapped") {
        auto p = make_pair(sine, fs, 20000, 21000, l);
        std::swap(p.rs, p.rc);
        const auto r = run_align(p, fs, false);
        CHECK_FALSE(r.ok);
        CHECK_THAT(r.error, Catch::StartsWith("the input is miswired: sin and cos swapped"));
    }
    SECTION("an inverted channel") {
        l.gc = -1;
        const auto p = make_pair(sine, fs, 20000, 21000, l);
        const auto r = run_align(p, fs, false);
        CHECK_FALSE(r.ok);
        CHECK_THAT(r.error, Catch::StartsWith("the input is miswired: the cos channel inverted"));
    }
    SECTION("a distorted record") {
        auto p = make_pair(sine, fs, 20000, 21000, l);
        for (auto* v : {&p.rs, &p.rc})
            for (auto& x : *v) x = std::clamp(x, -0.2, 0.2);  // clipped hard
        const auto r = run_align(p, fs, false);
        CHECK_FALSE(r.ok);
        CHECK_THAT(r.error, Catch::Contains("residual"));
    }
    SECTION("a played signal at rest") {
        auto p = make_pair([](double) { return 0.3; }, fs, 20000, 21000, l);
        const auto r = run_align(p, fs, false);
        CHECK_FALSE(r.ok);
        CHECK_THAT(r.error, Catch::Contains("constant"));
    }
}

TEST_CASE("own-clock loopback: plays, records delayed and warped, refuses what it does not simulate", "[align][device]") {
    auto d = dev::open("loopback:?own_clock=1&dac_bits=0&adc_bits=0&delay_s=1e-3&clock_ppm=50&gain=0.5&offset_v=0.1");
    const auto info = d->info();
    CHECK(info.can_play);
    CHECK(info.can_record);
    CHECK(info.own_clock);
    CHECK_FALSE(info.streaming);
    const double fs = 10000, f = 100;
    std::vector<double> s(5000), c(5000), rs(8000), rc(8000);
    for (std::size_t i = 0; i < s.size(); ++i) {
        s[i] = std::sin(kTwoPi * f * static_cast<double>(i) / fs);
        c[i] = std::cos(kTwoPi * f * static_cast<double>(i) / fs);
    }
    CHECK_THROWS_WITH(d->recorder()->record(rs, rc, fs, 1), Catch::Contains("nothing was played"));
    d->player()->play(s, c, fs, false);
    const auto r = d->recorder()->record(rs, rc, fs, 1);
    CHECK(r.status == dev::StreamStatus::Ok);
    CHECK(r.frames == 8000);
    CHECK(rs[5] == Approx(0.1));  // before the output arrives: the offset only
    for (std::size_t m : {100u, 2000u, 4321u}) {
        const double t = (static_cast<double>(m) / fs - 1e-3) * (1 + 50e-6);
        CHECK(rs[m] == Approx(0.1 + 0.5 * std::sin(kTwoPi * f * t)).margin(1e-6));
        CHECK(rc[m] == Approx(0.1 + 0.5 * std::cos(kTwoPi * f * t)).margin(1e-6));
    }
    CHECK(d->stream() == nullptr);  // a generator and a digitizer: no streams, no step mode
    CHECK(d->step() == nullptr);
    CHECK_THROWS_WITH(dev::open("loopback:?own_clock=1&latency_samples=3"), Catch::Contains("device.latency_samples"));
    CHECK_THROWS_WITH(dev::open("loopback:?delay_s=1e-3"), Catch::Contains("device.delay_s") && Catch::Contains("own_clock=1"));
    auto small = dev::open("loopback:?own_clock=1&max_play_samples=100");
    CHECK_THROWS_WITH(small->player()->play(s, c, fs, false), Catch::Contains("max_play_samples 100"));
    // The plain loopback is not an instrument.
    auto plain = dev::open("loopback:");
    CHECK_FALSE(plain->info().can_play);
    CHECK(plain->player() == nullptr);
    CHECK(plain->recorder() == nullptr);
}

TEST_CASE("run: output and input instruments on their own clocks score like the plain loopback", "[align][run]") {
    const Scenario plain = small_run("loopback:");
    // No offset here: atan2 has no offset correction, so 4 mV would add ~4e-3 rad to its error
    // (offsets are checked against analytic truth above).
    const std::string uri = "loopback:?own_clock=1&delay_s=2.345e-4&clock_ppm=-42&gain=0.97&noise_v=5e-5";
    Scenario two = plain;
    two.device.clear();
    two.instruments = Scenario::Instruments{uri, uri, ""};
    two.limits = {{"*", "alignment_delay_s", 2.3451e-4, 2.3449e-4, 0.0}, {"run", "clock_offset_ppm", -41.99, -42.01, 0.0},
                  {"*", "alignment_residual", 1e-3, std::nullopt, 0.0}};
    const json a = execute_run(plain), b = execute_run(two);
    REQUIRE(a["status"] == "done");
    INFO(b["error"].dump());
    REQUIRE(b["status"] == "done");
    const json& al = b["alignment"];
    CHECK(al["ok"] == true);
    CHECK(al["delay_s"].get<double>() == Approx(2.345e-4).margin(1e-9));
    CHECK(al["clock_offset_ppm"].get<double>() == Approx(-42).margin(0.01));
    CHECK(al["channels"]["sin"]["gain"].get<double>() == Approx(0.97).epsilon(1e-4));
    CHECK(al["channels"]["cos"]["offset_v"].get<double>() == Approx(0.0).margin(1e-5));
    CHECK(al["playback"]["mode"] == "once");
    CHECK(b["verdict"] == "PASS");
    int run_level = 0;
    for (const auto& m : b["measurements"])
        if (m["estimator"] == "run") {
            ++run_level;
            CHECK(m["outcome"] == "PASS");
        }
    CHECK(run_level == 3);
    CHECK(b["samples"]["processed"] == a["samples"]["processed"]);
    // Same estimator, same signal: the scores agree within what the link adds (gain, a little noise).
    const double ra = a["estimators"][0]["metrics"]["rms"]["rad"].get<double>(), rb = b["estimators"][0]["metrics"]["rms"]["rad"].get<double>();
    CHECK(rb == Approx(ra).epsilon(0.1));
    // No ringing from the output's start or end inside the scored frames (the playback runs
    // beyond them): the worst error stays that of the noise.
    CHECK(b["estimators"][0]["metrics"]["max_abs"]["rad"].get<double>() < 1.5 * a["estimators"][0]["metrics"]["max_abs"]["rad"].get<double>());
    CHECK(std::fabs(b["estimators"][0]["metrics"]["mean"]["rad"].get<double>()) < 2e-5);  // no phase bias from the delay
    CHECK(b["estimators"][0]["metrics"]["slipped_samples"] == 0);
    // The single-URI form of the same device is the same run.
    Scenario one = plain;
    one.device = uri;
    const json c = execute_run(one);
    CHECK(c["alignment"]["delay_s"] == al["delay_s"]);
    // A plain loopback run has no alignment: a limit on it fails as not measured.
    Scenario p2 = plain;
    p2.limits = {{"*", "clock_offset_ppm", 100.0, std::nullopt, 0.0}};
    const json d = execute_run(p2);
    CHECK(d["alignment"].is_null());
    CHECK(d["verdict"] == "FAIL");
    CHECK_THAT(d["measurements"].back()["reason"].get<std::string>(), Catch::Contains("not measured") && Catch::Contains("no alignment"));
}

TEST_CASE("run: a generator memory too small plays whole cycles cyclically, or fails naming the limit", "[align][run]") {
    Scenario sc = small_run("");
    const std::string uri = "loopback:?own_clock=1&delay_s=1e-4&clock_ppm=20&noise_v=5e-5&max_play_samples=5000";
    sc.device = uri;
    json r = execute_run(sc);
    INFO(r["error"].dump());
    REQUIRE(r["status"] == "done");
    CHECK(r["alignment"]["playback"]["mode"] == "cyclic");
    CHECK(r["alignment"]["playback"]["samples"].get<int>() <= 5000);
    CHECK(r["alignment"]["delay_s"].get<double>() == Approx(1e-4).margin(1e-9));
    CHECK(r["estimators"][0]["metrics"]["rms"]["rad"].get<double>() < 1e-3);
    sc.motion.kind = MotionKind::Ramp;
    sc.motion.accel_rad_s2 = 1.0;
    r = execute_run(sc);
    CHECK(r["verdict"] == "ERROR");
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("max_play_samples") && Catch::Contains("constant-speed"));
}

namespace {
// 0.2 s at 100 kHz: the playback is 64 + 20000 + 84 = 20148 samples (lead, run, tail).
constexpr std::size_t kSegRunPlay = 20148;
const std::string kSegLink = "loopback:?own_clock=1&delay_s=1e-4&clock_ppm=20&noise_v=5e-5";
// An accelerating ramp (1 -> 2 kHz electrical over the run) or a reversal (a 5 Hz swing of
// 0.3 rad: the speed passes through zero twice).
Scenario segmented_motion(const std::string& kind) {
    Scenario sc = small_run("");
    const double per_hz = kTwoPi / 1024;  // shaft rad/s per electrical Hz
    if (kind == "ramp") {
        sc.motion.kind = MotionKind::Ramp;
        sc.motion.velocity_rad_s = 1000 * per_hz;
        sc.motion.accel_rad_s2 = 5000 * per_hz;
    } else {
        sc.motion.kind = MotionKind::Sine;
        sc.motion.velocity_rad_s = 0;
        sc.motion.amplitude_rad = 0.3;
        sc.motion.freq_hz = 5;
    }
    return sc;
}
double atan2_rms_rad(const json& r) { return r["estimators"][0]["metrics"]["rms"]["rad"].get<double>(); }
}  // namespace

TEST_CASE("run: a non-periodic run 4-10x the generator memory plays in segments and scores like an unlimited generator", "[align][run][segmented]") {
    for (const std::string kind : {"ramp", "reversal"}) {
        Scenario sc = segmented_motion(kind);
        sc.device = kSegLink;
        const json ref = execute_run(sc);
        INFO(kind << " " << ref["error"].dump());
        REQUIRE(ref["status"] == "done");
        CHECK(ref["alignment"]["playback"]["mode"] == "once");
        for (const std::size_t memory : {std::size_t{5000}, std::size_t{2100}}) {
            sc.device = kSegLink + "&max_play_samples=" + std::to_string(memory) + "&max_segments=64";
            const json r = execute_run(sc);
            INFO("memory " << memory << " " << r["error"].dump());
            REQUIRE(r["status"] == "done");
            const json& pb = r["alignment"]["playback"];
            CHECK(pb["mode"] == "segmented");
            const auto segments = pb["segments"].get<std::size_t>(), seg = pb["segment_samples"].get<std::size_t>();
            CHECK(segments == (kSegRunPlay + memory - 1) / memory);  // 5 and 10 segments
            CHECK(seg <= memory);
            CHECK((segments - 1) * seg < kSegRunPlay);
            CHECK(segments * seg >= kSegRunPlay);
            CHECK(r["alignment"]["delay_s"].get<double>() == Approx(1e-4).margin(1e-9));
            CHECK(r["alignment"]["clock_offset_ppm"].get<double>() == Approx(20).margin(0.01));
            CHECK(r["estimators"][0]["metrics"]["slipped_samples"] == 0);
            // Every segment lies where the one alignment puts it.
            REQUIRE(pb["segment_offsets_samples"].size() == segments);
            for (const auto& v : pb["segment_offsets_samples"]) CHECK(std::fabs(v.get<double>()) < 1e-3);
            const double ra = atan2_rms_rad(ref), rb = atan2_rms_rad(r);
            INFO("atan2 rms rad: unlimited " << ra << ", segmented " << rb);
            CHECK(rb < 1.2 * ra);
            CHECK(rb > ra / 1.2);
            CHECK(r["estimators"][0]["metrics"]["max_abs"]["rad"].get<double>() < 1.5 * ref["estimators"][0]["metrics"]["max_abs"]["rad"].get<double>());
        }
    }
}

TEST_CASE("run: a sample dropped or repeated at every segment join is caught", "[align][run][segmented]") {
    for (const std::string kind : {"ramp", "reversal"}) {
        Scenario sc = segmented_motion(kind);
        sc.device = kSegLink + "&max_play_samples=5000&max_segments=64";
        const json good = execute_run(sc);
        REQUIRE(good["status"] == "done");
        for (const int slip : {-1, 1}) {
            sc.device = kSegLink + "&max_play_samples=5000&max_segments=64&join_slip_samples=" + std::to_string(slip);
            const json r = execute_run(sc);
            INFO(kind << " slip " << slip << " " << r.value("error", json()).dump() << " " << r["alignment"].dump());
            // The output runs one more sample (10 us) off the played signal after each join. The
            // alignment alone would take the slips for a clock offset (some 200 ppm) and the
            // scores would be 100x worse; the segments' own time shifts disagree instead.
            CHECK(r["verdict"] == "ERROR");
            CHECK_THAT(r.value("error", std::string()), Catch::Contains("segment joins") && Catch::Contains("dropped or repeated"));
            CHECK(r["samples"]["processed"] == 0);
            double spread = 0;
            for (const auto& v : r["alignment"]["playback"]["segment_offsets_samples"]) spread = std::max(spread, std::fabs(v.get<double>()));
            CHECK(spread > 0.05);
        }
    }
}

TEST_CASE("run: segmented playback at the memory's edges, over the segment limit, and a generator lost mid-sequence", "[align][run][segmented]") {
    Scenario sc = segmented_motion("ramp");
    // Exactly the memory: one playback.
    sc.device = kSegLink + "&max_play_samples=" + std::to_string(kSegRunPlay) + "&max_segments=4";
    json r = execute_run(sc);
    INFO(r["error"].dump());
    REQUIRE(r["status"] == "done");
    CHECK(r["alignment"]["playback"]["mode"] == "once");
    CHECK(r["alignment"]["playback"]["samples"] == kSegRunPlay);
    // One sample over: two segments of equal length (not one full and one of a sample).
    sc.device = kSegLink + "&max_play_samples=" + std::to_string(kSegRunPlay - 1) + "&max_segments=4";
    r = execute_run(sc);
    REQUIRE(r["status"] == "done");
    CHECK(r["alignment"]["playback"]["mode"] == "segmented");
    CHECK(r["alignment"]["playback"]["segments"] == 2);
    CHECK(r["alignment"]["playback"]["segment_samples"] == kSegRunPlay / 2);
    CHECK(r["estimators"][0]["metrics"]["slipped_samples"] == 0);
    // More segments than the generator allows: refused before playing, naming the limits.
    sc.device = kSegLink + "&max_play_samples=5000&max_segments=4";
    r = execute_run(sc);
    CHECK(r["verdict"] == "ERROR");
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("max_play_samples") && Catch::Contains("at most 5000 samples it needs 5 segments") &&
                                                  Catch::Contains("the generator's 4 (max_segments)"));
    CHECK(r["samples"]["processed"] == 0);
    // A generator without segmented playback: the refusal says so and why.
    sc.device = kSegLink + "&max_play_samples=5000";
    r = execute_run(sc);
    CHECK(r["verdict"] == "ERROR");
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("cannot play it in segments") && Catch::Contains("max_segments > 0"));
    // Lost when segment 2 of 5 is due: ERROR naming it, the report keeps the playback planned.
    sc.device = kSegLink + "&max_play_samples=5000&max_segments=64&fail_at_segment=2";
    r = execute_run(sc);
    CHECK(r["verdict"] == "ERROR");
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("lost when segment 2 of 5") && Catch::Contains("mid-sequence"));
    CHECK(r["alignment"]["playback"]["mode"] == "segmented");
    CHECK(r["alignment"]["playback"]["segments"] == 5);
    CHECK(r["samples"]["processed"] == 0);
}

TEST_CASE("loopback: play_segments checks the limits and plays the signal back to back", "[align][segmented]") {
    auto d = dev::open("loopback:?own_clock=1&max_play_samples=100&max_segments=3&dac_bits=0&adc_bits=0&noise_lsb=0");
    dev::PlayPort* p = d->player();
    REQUIRE(p);
    dev::SequencePort* q = p->sequencer();
    REQUIRE(q);
    CHECK(q->sequence_limits().max_segments == 3);
    CHECK(q->sequence_limits().max_segment_samples == 100);
    std::vector<double> s(250), c(250);
    for (std::size_t i = 0; i < s.size(); ++i) { s[i] = std::sin(0.05 * static_cast<double>(i)); c[i] = std::cos(0.05 * static_cast<double>(i)); }
    CHECK_THROWS_WITH(q->play_segments(s, c, 101, 1000), Catch::Contains("max_segments") && Catch::Contains("16..100"));
    CHECK_THROWS_WITH(q->play_segments(s, c, 80, 1000), Catch::Contains("4 segments"));
    CHECK_THROWS_WITH(q->play_segments(s, c, 124, 1000), Catch::Contains("the last 2"));
    q->play_segments(s, c, 100, 1000);
    // Recorded at the played rate with no delay: the played samples come back.
    std::vector<double> rs(250), rc(250);
    REQUIRE(d->recorder()->record(rs, rc, 1000, 1).status == dev::StreamStatus::Ok);
    double worst = 0;
    for (std::size_t i = 0; i < s.size(); ++i) worst = std::max({worst, std::fabs(rs[i] - s[i]), std::fabs(rc[i] - c[i])});
    CHECK(worst < 1e-9);
    CHECK_FALSE(dev::open("loopback:?own_clock=1&max_play_samples=100")->player()->sequencer());
}

TEST_CASE("run: unalignable instruments end the run as ERROR naming why", "[align][run]") {
    Scenario sc = small_run("loopback:?own_clock=1&gain=0&noise_v=1e-3");  // the input sees noise only
    json r = execute_run(sc);
    CHECK(r["verdict"] == "ERROR");
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("alignment not confident") && Catch::Contains("no correlation"));
    CHECK(r["alignment"]["ok"] == false);
    CHECK(r["samples"]["processed"] == 0);
    sc.device = "loopback:?own_clock=1&swap_channels=1&noise_v=1e-4";
    r = execute_run(sc);
    CHECK(r["verdict"] == "ERROR");
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("miswired: sin and cos swapped"));
    // Two distinct loopbacks are two instances: the input never saw the output.
    sc.device.clear();
    sc.instruments = Scenario::Instruments{"loopback:?own_clock=1", "loopback:?own_clock=1&seed=2", ""};
    r = execute_run(sc);
    CHECK(r["verdict"] == "ERROR");
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("device.input") || Catch::Contains("nothing was played"));
    // A streaming device is not a generator.
    sc.instruments = Scenario::Instruments{"loopback:", "loopback:?own_clock=1", ""};
    r = execute_run(sc);
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("device.output") && Catch::Contains("cannot play"));
}

TEST_CASE("scenario: device as output and input instruments, errors name the field", "[align][config]") {
    json j = load_json_file(fixture("loopback-two-clocks.json"));
    const std::string base = std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios";
    Scenario sc = scenario_from_json(j, base);
    REQUIRE(sc.instruments);
    CHECK(sc.device.empty());
    CHECK(json(sc)["device"]["output"] == j["device"]["output"]);
    CHECK(scenario_from_json(json(sc), base).instruments->input == sc.instruments->input);  // round trip
    CHECK_NOTHROW(plan_run(sc));
    json bad = j;
    bad["device"]["input"] = "loopback:?adc_bitz=3";
    CHECK_THROWS_WITH(plan_run(scenario_from_json(bad, base)), Catch::Contains("device.input.adc_bitz"));
    try {
        plan_run(scenario_from_json(bad, base));
    } catch (const ConfigError& e) {
        CHECK(e.field() == "device.input.adc_bitz");
    }
    bad = j;
    bad["device"]["input"] = "warp:";
    try {
        plan_run(scenario_from_json(bad, base));
        FAIL("no error");
    } catch (const ConfigError& e) {
        CHECK(e.field() == "device.input");
        CHECK_THAT(e.message(), Catch::Contains("unknown driver 'warp'"));
    }
    bad = j;
    bad["device"].erase("input");
    CHECK_THROWS_WITH(scenario_from_json(bad, base), Catch::Contains("device.input"));
    bad = j;
    bad["device"]["inputs"] = "loopback:";
    CHECK_THROWS_WITH(scenario_from_json(bad, base), Catch::Contains("device.inputs"));
    bad = j;
    bad["device"] = 5;
    CHECK_THROWS_WITH(scenario_from_json(bad, base), Catch::Contains("device URI or"));
    bad = j;
    bad["device"]["dut"] = "modbus+tcp://127.0.0.1:1502";
    try {
        plan_run(scenario_from_json(bad, base));
        FAIL("no error");
    } catch (const ConfigError& e) {
        CHECK(e.field() == "device.dut");
        CHECK_THAT(e.message(), Catch::Contains("not supported yet"));
    }
    bad["device"]["dut"] = "modbus+tcp://127.0.0.1:1502?bogus=1";
    CHECK_THROWS_WITH(plan_run(scenario_from_json(bad, base)), Catch::Contains("device.dut.bogus"));
    // Run-level metrics are measured once: an estimator label on them is refused.
    Scenario s2 = sc;
    s2.limits = {{"atan2", "clock_offset_ppm", 1.0, std::nullopt, 0.0}};
    CHECK_THROWS_WITH(plan_run(s2), Catch::Contains("limits[0].estimator") && Catch::Contains("once for the run"));
    CHECK(find_metric("alignment_delay_s")->run_level);
}

TEST_CASE("service: the --allow-device policy holds for output and input instruments alike", "[align][service]") {
    const auto dir = std::filesystem::temp_directory_path() / ("fringe-align-" + std::to_string(getpid()) + "-" + std::to_string(std::random_device{}()));
    std::filesystem::create_directories(dir);
    {
        ServiceConfig c;
        c.data_dir = dir.string();
        c.fixtures_dir = FRINGE_SOURCE_DIR "/fixtures";
        c.web_dir = FRINGE_SOURCE_DIR "/web";
        c.token = "0123456789abcdef0123456789abcdef";
        c.allow_devices = {"modbus+tcp://127.0.0.1:*"};
        Service s(c);
        auto post = [&](const json& sc) {
            HttpRequest r;
            r.method = "POST";
            r.target = "/api/v1/runs";
            r.body = json{{"scenario", sc}}.dump();
            r.headers["authorization"] = "Bearer " + c.token;
            return s.handle(r);
        };
        json sc = load_json_file(fixture("loopback-two-clocks.json"));
        sc["duration_s"] = 0.1;
        sc["settle_s"] = 0.01;
        sc["limits"] = json::array();
        const std::string own = sc["device"]["output"];
        for (const char* side : {"output", "input"}) {
            json bad = sc;
            bad["device"][side] = "modbus+tcp://10.0.0.9:502?board=generic-aio";
            const auto r = post(bad);
            CHECK(r.status == 403);
            const json e = json::parse(r.body)["error"];
            CHECK(e["code"] == "device_not_allowed");
            CHECK(e["field"] == std::string("scenario.device.") + side);
            bad["device"][side] = "loopback:?adc_bitz=3";
            const auto r2 = post(bad);
            CHECK(r2.status == 400);
            CHECK(json::parse(r2.body)["error"]["field"] == std::string("scenario.device.") + side + ".adc_bitz");
        }
        // An allowed board as the input passes the policy (the run then finds it is no digitizer).
        json ok = sc;
        ok["device"]["input"] = "modbus+tcp://127.0.0.1:1?board=generic-aio";
        CHECK(post(ok).status == 201);
        // The fixture's instruments run and are aligned.
        const auto r = post(sc);
        REQUIRE(r.status == 201);
        const std::string id = json::parse(r.body)["id"];
        std::uint64_t seq = 0;
        for (int i = 0; i < 600; ++i) {
            const auto snap = s.runs().wait_change(id, seq, 200);
            REQUIRE(snap);
            if (snap->finished()) break;
            seq = snap->seq;
        }
        CHECK(s.runs().snapshot(id)->device == own);  // one instrument: its URI
        HttpRequest g;
        g.method = "GET";
        g.target = "/api/v1/runs/" + id + "/report.json";
        const json rep = json::parse(s.handle(g).body);
        CHECK(rep["status"] == "done");
        CHECK(rep["alignment"]["ok"] == true);
        CHECK(rep["alignment"]["delay_s"].get<double>() == Approx(3.21e-4).margin(1e-8));
        s.shutdown();
    }
    std::filesystem::remove_all(dir);
}

// Issue 22: conditions the docs support (clock offsets up to 1000 ppm, a record that starts after
// the output) were aligned confidently wrong; wiring faults that amount to a phase shift were
// taken for a delay; a flat channel passed `gain > 0`; one absurd sample broke the correlation.
TEST_CASE("align: clock offsets across the supported range, a periodic signal", "[align][issue22]") {
    const double fs = 100000;
    auto sine = [](double t) { return kTwoPi * 1234.5 * t + 0.4; };  // 81 samples a cycle
#ifdef FRINGE_SANITIZED_BUILD
    const std::vector<double> ppms = {-999.0, 999.0};  // the ends of the range; Release sweeps it
#else
    const std::vector<double> ppms = {-999.0, -400.0, -150.0, 150.0, 400.0, 999.0};
#endif
    for (double ppm : ppms) {
        for (double delay_s : {1.23456e-3, -0.3e-3}) {  // the record starting before, and after, the output
            Link l;
            l.delay_s = delay_s;
            l.ppm = ppm;
            l.gs = 0.95; l.gc = 0.93; l.os = 0.002;
            l.noise_v = 1e-4;
            const auto p = make_pair(sine, fs, 20000, 21000, l);
            const auto r = run_align(p, fs, false);
            INFO("ppm " << ppm << ", delay " << delay_s << ": " << r.error << " (delay " << r.delay_s << ", ppm " << r.clock_offset_ppm << ")");
            REQUIRE(r.ok);
            CHECK(std::fabs(r.delay_s - l.delay_s) * fs < 2e-3);
            CHECK(std::fabs(r.clock_offset_ppm - l.ppm) < 0.05);
            CHECK(r.ambiguity_z > 10);
        }
    }
}

TEST_CASE("align: refused by name: wiring, flat channels, clock offsets out of range", "[align][issue22]") {
    const double fs = 100000;
    auto sine = [](double t) { return kTwoPi * 1234.5 * t + 0.4; };
    Link l;
    l.delay_s = 0.321e-3;
    l.ppm = 25;
    l.noise_v = 1e-4;
    auto refused = [&](const Link& link, bool swap, const std::string& text) {
        auto p = make_pair(sine, fs, 20000, 21000, link);
        if (swap) std::swap(p.rs, p.rc);
        const auto r = run_align(p, fs, false);
        INFO(text << ": got " << (r.ok ? "ok" : r.error) << " (delay " << r.delay_s << " s)");
        CHECK_FALSE(r.ok);
        CHECK_THAT(r.error, Catch::Contains(text));
        return r;
    };
    SECTION("both channels inverted: half a period from a delay, told apart by the output's edges") {
        Link b = l;
        b.gs = b.gc = -1;
        refused(b, false, "miswired: both channels inverted");
        b.ppm = 999;
        refused(b, false, "miswired: both channels inverted");
    }
    SECTION("swapped, one inverted: a quarter period from a delay") {
        Link b = l;
        b.gc = -1;  // the record's sin shows -cos after the swap below
        refused(b, true, "miswired: sin and cos swapped");
    }
    SECTION("a flat channel, on several seeds, and one at 5 % of the other") {
        for (std::uint64_t seed : {1u, 2u, 3u, 4u}) {
            Link b = l;
            b.gc = 0;
            auto p = make_pair(sine, fs, 20000, 21000, b, seed);
            const auto r = run_align(p, fs, false);
            INFO("seed " << seed << ": " << r.error);
            CHECK_FALSE(r.ok);
            CHECK_THAT(r.error, Catch::StartsWith("the cos channel is flat") && Catch::Contains(" V"));
        }
        Link b = l;
        b.gs = 0.05;
        refused(b, false, "the sin channel is flat");
    }
    SECTION("clock offsets beyond the supported 1000 ppm are named as such") {
        for (double ppm : {1500.0, -1500.0}) {
            Link b = l;
            b.ppm = ppm;
            const auto r = refused(b, false, "out of the supported range");
            CHECK(std::fabs(r.clock_offset_ppm - ppm) < 1);
        }
    }
}

TEST_CASE("align: one absurd or non-finite sample is left out", "[align][issue22]") {
    const double fs = 100000;
    Link l;
    l.delay_s = 0.321e-3;
    l.ppm = 25;
    l.noise_v = 1e-4;
    for (double bad : {1e300, -50.0, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
        auto p = make_pair([](double t) { return kTwoPi * 1234.5 * t; }, fs, 20000, 21000, l);
        p.rs[5000] = bad;
        p.rc[9000] = bad;
        const auto r = run_align(p, fs, false);
        INFO(bad << ": " << r.error);
        REQUIRE(r.ok);
        CHECK(r.outlier_samples == 2);
        CHECK(std::fabs(r.delay_s - l.delay_s) * fs < 2e-3);
        CHECK(r.residual_rms_v == Approx(1e-4).epsilon(0.05));
    }
    // Many of them are the digitizer's problem, named.
    auto p = make_pair([](double t) { return kTwoPi * 1234.5 * t; }, fs, 20000, 21000, l);
    for (std::size_t m = 0; m < p.rs.size(); m += 50) p.rs[m] = 1e300;
    const auto r = run_align(p, fs, false);
    CHECK_FALSE(r.ok);
    CHECK_THAT(r.error, Catch::Contains("are not finite or lie beyond"));
}

}  // namespace test_align_cpp
