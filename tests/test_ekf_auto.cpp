// ekf-auto (issue 13): told nothing, compared with an EKF that knows the true model (the
// oracle: the generator's own profile, the same CA kinematics and fn) and with the PCRB of its
// declared prior, on every kind of signal of the issue: phase-error std within 1.5x of the
// larger of the two after the kind's settling time, zero slipped samples, six seeds.
#include "estimator_helpers.hpp"
#include "signal_kinds.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <random>
#include <tuple>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_ekf_auto_cpp {

using namespace fringe;
using namespace fringe::test;
using nlohmann::json;

namespace {
constexpr double kFs = 100e3;
constexpr double kSettleS = 0.5;  // acquisition, bootstrap and 16 cycles of shape memory at ~100 Hz electrical

SignalKind kind_named(const std::string& name) {
    for (auto& k : signal_kinds())
        if (k.name == name) return k;
    throw std::runtime_error("no kind " + name);
}

TEST_CASE("ekf-auto is registered, needs no parameters and declares its prior", "[estimator][ekf-auto]") {
    const auto& info = est::find("ekf-auto");
    for (const auto& p : info.params) {
        INFO(p.name);
        CHECK(!p.default_value.is_null());  // every parameter optional
        CHECK(!p.description.empty());
    }
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = kFs;
    auto e = est::make("ekf-auto", cfg);  // no encoder, no params
    REQUIRE(e->prior());
    CHECK(e->prior()->kinematics == est::Kinematics::CA);
    CHECK(e->prior()->natural_freq_hz == 100.0);
    cfg.params = {{"max_order", 3}};
    CHECK_THROWS_WITH(est::make("ekf-auto", cfg), Catch::Contains("params.max_order"));
}

// The issue-13 suite: every kind of signal, with its oracle (an EKF told the generator's own
// profile, with the same CA kinematics and fn) and duration. Shared by the accuracy test and
// the table printer (docs/estimators.md).
struct SuiteKind {
    SignalKind kind;
    std::string oracle;
    json oracle_params;
    double duration_s = 1.0;
    double settle_s = kSettleS;  // ekf-auto's settling time on this kind (scored after it)
    double target = 1.5;         // ekf-auto std / max(oracle, PCRB) it must stay below
};

std::vector<SuiteKind> suite() {
    std::vector<SuiteKind> s;
    const json ca{{"kinematics", "ca"}};
    const double f_paper = 106.72358591248666;
    s.push_back({kind_named("ideal-16bit"), "ekf-ideal", ca});
    s.push_back({kind_named("ideal-10bit"), "ekf-ideal", ca});
    s.push_back({kind_named("paper-duty1p6"), "ekf-diffraction", ca});
    s.push_back({{"paper-312spc", fixture_encoder("paper-duty1p6"), constant_electrical(kFs / 312, 1024)}, "ekf-diffraction", ca});
    s.push_back({{"paper-8433spc", fixture_encoder("paper-duty1p6"), constant_electrical(kFs / 8433, 1024)}, "ekf-diffraction", ca, 3.0, 1.5});
    s.push_back({{"duty6-12bit", diffraction_w(2.0, 12), constant_electrical(f_paper, 1024)}, "ekf-diffraction", ca});
    s.push_back({{"duty10-10bit", diffraction_w(0.5, 10), constant_electrical(f_paper, 1024)}, "ekf-diffraction", ca});
    s.push_back({kind_named("acceleration"), "ekf-diffraction", ca});
    s.push_back({kind_named("light-drift"), "ekf-diffraction", {{"kinematics", "ca"}, {"agc", true}, {"q_gain_per_s", 0.01}}});
    // the shape's variation is learnt over one revolution of the gap's swing (0.6 s); where
    // eccentricity takes kappa just below 1 the diffraction shape has a kink (its 2nd harmonic
    // stops at 0 while the fundamental goes on changing), followed by v, not by the learnt u
    s.push_back({kind_named("runout"), "ekf-diffraction", {{"kinematics", "ca"}, {"track_kappa", true}, {"q_kappa_per_s", 0.01}}, 2.0, 1.0});
    // ekf-ideal has no harmonic model: the oracle is the shape-table tracker told the exact shape,
    // and told a bandwidth that suits the motion (fn = 500 Hz, the best of 100-1000 Hz on this
    // motion): the fixed 100 Hz of the other oracles lags the jerk by ~4e-3 rad
    s.push_back({kind_named("reversals"), "ekf-auto",
                 {{"learn", false}, {"start_from_profile", true}, {"adaptive_bandwidth", false}, {"natural_freq_hz", 500.0}}});
    // slow reversals (found by a new-user trial): the paper signal swinging +-20 rad electrical
    // at 1 Hz (20 Hz electrical peak, 5000+ samples per cycle, acceleration throughout): each
    // point's acceleration correction reaches 0.05 rad, so the shape is learnt over ~3-4 swings
    {
        MotionProfile m;
        m.kind = MotionKind::Sine;
        m.freq_hz = 1.0;
        m.amplitude_rad = 20.0 / 1024;
        s.push_back({{"slow-reversals", fixture_encoder("paper-duty1p6"), m}, "ekf-diffraction", ca, 6.0, 4.0});
    }
    return s;
}

struct Row {
    double oracle, pcrb, automatic;
    ErrorMetrics m;
    json state;
};

Row measure(const SuiteKind& k, std::uint64_t seed) {
    const auto n = static_cast<std::size_t>(k.duration_s * kFs);
    const Block b = generate(k.kind.encoder, k.kind.motion, kFs, n, seed);
    auto a = run_estimator("ekf-auto", json::object(), std::nullopt, b, kFs, k.kind.encoder, k.settle_s);
    auto o = run_estimator(k.oracle, k.oracle_params, k.kind.encoder, b, kFs, k.kind.encoder, k.settle_s);
    return {o.m.std_rad, a.bounds["pcrb_rad"].get<double>(), a.m.std_rad, a.m, a.e->state()};
}
}  // namespace

// Hidden (minutes under ASan+UBSan): run in the Release build's estimator.long entry.
TEST_CASE("ekf-auto told nothing tracks within 1.5x of the oracle or the PCRB", "[estimator][ekf-auto][accuracy][long][.long]") {
    for (const auto& k : suite()) {
        for (std::uint64_t seed : {3, 4, 5, 6, 7, 8}) {
            const Row r = measure(k, seed);
            INFO(k.kind.name << " seed " << seed << ": ekf-auto std " << r.automatic << ", oracle " << r.oracle << ", PCRB " << r.pcrb
                             << " state " << r.state.dump());
            CHECK(r.m.slipped_samples == 0);
            CHECK(r.m.invalid_after_settle == 0);
            CHECK(r.automatic < k.target * std::max(r.oracle, r.pcrb));
        }
    }
}

// Prints the table of docs/estimators.md: build/tests/fringe_tests "[ekf-auto-table]"
// (seed 3's numbers, and the worst ratio and the slips over the test's six seeds)
TEST_CASE("ekf-auto table", "[.ekf-auto-table]") {
    std::printf("| kind | oracle | PCRB | ekf-auto | ratio | worst ratio, seeds 3-8 | settle s | slipped, seeds 3-8 |\n");
    for (const auto& k : suite()) {
        const Row r = measure(k, 3);
        double worst = 0;
        long long slipped = 0;
        for (std::uint64_t seed = 3; seed <= 8; ++seed) {
            const Row q = seed == 3 ? r : measure(k, seed);
            worst = std::max(worst, q.automatic / std::max(q.oracle, q.pcrb));
            slipped += static_cast<long long>(q.m.slipped_samples);
        }
        std::printf("| %s | %.3g | %.3g | %.3g | %.2f | %.2f | %.1f | %lld |\n", k.kind.name.c_str(), r.oracle, r.pcrb, r.automatic,
                    r.automatic / std::max(r.oracle, r.pcrb), worst, k.settle_s, slipped);
        std::fflush(stdout);
    }
}

// Issue 28: the same kinds, but short: 0.6 s captures scored from 0.1 s (about ten electrical
// cycles of learning), with this file's own parameters and seeds. The oracle is an EKF told the
// model; on the motions with jerk, told also the bandwidth that suits the motion (the best of a
// scan of fn: the informed filter a user would tune), so ekf-auto must choose its own.
struct ShortKind {
    std::string name;
    EncoderProfile encoder;
    MotionProfile motion;
    std::string oracle;
    json oracle_params;
    std::vector<double> oracle_fn_hz{};  // non-empty: the oracle's fn is the best of these
    double target = 1.5;                 // 0: a kind it is known to miss, printed in the table, not checked
};

constexpr double kShortS = 0.6, kShortSettleS = 0.1;

std::vector<ShortKind> short_suite() {
    std::vector<ShortKind> s;
    const json ca{{"kinematics", "ca"}};
    const int lines = 1024;
    {  // ideal quadrature with noise and a 0.1 % amplitude mismatch, 16 and 10 bit
        auto e = clean_ideal(lines);
        e.noise.sigma_add_v = 3e-4;
        e.noise.sigma_gain = 1e-4;
        e.lissajous.gain_mismatch = -1e-3;
        e.adc.bits = 16;
        s.push_back({"short-ideal-16bit", e, constant_electrical(93.1, lines), "ekf-ideal", ca});
        e.adc.bits = 10;
        s.push_back({"short-ideal-10bit", e, constant_electrical(121.3, lines), "ekf-ideal", ca});
    }
    s.push_back({"short-paper-duty1p6", fixture_encoder("paper-duty1p6"), constant_electrical(98.4, lines), "ekf-diffraction", ca});
    {  // eccentricity and gap run-out on a 32-line disc that turns twice in the capture
        auto e = fixture_encoder("eccentricity-runout");
        e.lines_per_rev = 32;
        s.push_back({"short-runout-32", e, constant_electrical(2 * 32 / kShortS, 32), "ekf-diffraction",
                     {{"kinematics", "ca"}, {"track_kappa", true}, {"q_kappa_per_s", 0.01}}});
    }
    {  // light-source gain drift, +-4 % at 1.5 Hz
        auto e = fixture_encoder("agc-drift");
        e.noise.drift_amplitude = 0.04;
        e.noise.drift_freq_hz = 1.5;
        s.push_back({"short-light-drift", e, constant_electrical(103.0, lines), "ekf-diffraction",
                     {{"kinematics", "ca"}, {"agc", true}, {"q_gain_per_s", 0.01}}});
        // a fast large drift, +-6 % at 3 Hz (its period covered under twice by the capture):
        // the gain rises 6 % in the first 0.083 s and falls 12 % in the next 0.17 s
        e.noise.drift_amplitude = 0.06;
        e.noise.drift_freq_hz = 3.0;
        s.push_back({"short-light-drift-fast", e, constant_electrical(103.0, lines), "ekf-diffraction",
                     {{"kinematics", "ca"}, {"agc", true}, {"q_gain_per_s", 0.01}}});
    }
    {  // an accelerating ramp (15 -> ~900 Hz electrical in 0.6 s) with small offsets
        auto e = fixture_encoder("paper-duty1p6");
        e.lissajous.offset_sin_v = -0.006;
        e.lissajous.offset_cos_v = 0.009;
        MotionProfile m;
        m.kind = MotionKind::Ramp;
        m.velocity_rad_s = kTwoPi * 15.0 / lines;
        m.accel_rad_s2 = 9.3e3 / lines;
        s.push_back({"short-ramp", e, m, "ekf-diffraction", ca});
    }
    {  // an oscillation with velocity reversals (4 Hz, peak 160 Hz electrical), Lissajous errors, a 3rd harmonic
        auto e = clean_ideal(lines);
        e.noise.sigma_add_v = 2e-4;
        e.noise.sigma_gain = 1e-4;
        e.adc.bits = 16;
        e.lissajous = {-0.015, 0.01, 0.02, -0.025};
        e.harmonics = {{3, 0.015, 1.1}};
        MotionProfile m;
        m.kind = MotionKind::Sine;
        m.freq_hz = 4.0;
        m.amplitude_rad = 160.0 / 4.0 / lines;
        m.phase_rad = 0.7;
        // ekf-ideal has no harmonic model: the oracle is the shape-table tracker told the exact shape
        s.push_back({"short-reversals", e, m, "ekf-auto", {{"learn", false}, {"start_from_profile", true}, {"adaptive_bandwidth", false}},
                     {100, 200, 300, 400, 500, 700, 1000}});
    }
    // Known misses (target 0), found trying it as a user would (2026-11-28):
    {  // gap run-out whose kappa crosses 1 (0.98-1.10), where the diffraction model's 2nd harmonic
       // is cut off: the shape varies along two directions, and ekf-auto learns one (9x, in
       // steady state too)
        auto e = fixture_encoder("eccentricity-runout");
        e.lines_per_rev = 32;
        e.gap_d1_cm = 0.76;
        e.gap_d2_cm = 0.68;
        s.push_back({"short-runout-32-kappa-below-1", e, constant_electrical(2 * 32 / kShortS, 32), "ekf-diffraction",
                     {{"kinematics", "ca"}, {"track_kappa", true}, {"q_kappa_per_s", 0.01}}, {}, 0.0});
    }
    {  // reversals that travel only ~6 electrical cycles in the first 0.1 s (3 Hz, 130 Hz peak,
       // starting near the peak speed), larger Lissajous errors, no harmonic: learnt by 0.15 s,
       // at the bound after it (1.02x from 1 s), 2x from 0.1 s
        auto e = clean_ideal(lines);
        e.noise.sigma_add_v = 3e-4;
        e.lissajous = {0.02, 0.015, -0.01, 0.02};
        MotionProfile m;
        m.kind = MotionKind::Sine;
        m.freq_hz = 3.0;
        m.amplitude_rad = 130.0 / 3.0 / lines;
        m.phase_rad = 0.3;
        s.push_back({"short-reversals-slow-start", e, m, "ekf-ideal", ca, {100, 200, 300, 400, 500, 700, 1000}, 0.0});
    }
    return s;
}

struct ShortRow {
    double oracle, oracle_fn, pcrb, automatic;
    ErrorMetrics m;
    json state;
};

ShortRow measure_short(const ShortKind& k, std::uint64_t seed) {
    const auto n = static_cast<std::size_t>(kShortS * kFs);
    const Block b = generate(k.encoder, k.motion, kFs, n, seed);
    auto a = run_estimator("ekf-auto", json::object(), std::nullopt, b, kFs, k.encoder, kShortSettleS);
    double best = std::numeric_limits<double>::infinity(), best_fn = 100;
    for (const double fn : k.oracle_fn_hz.empty() ? std::vector<double>{0} : k.oracle_fn_hz) {
        json p = k.oracle_params;
        if (fn > 0) p["natural_freq_hz"] = fn;
        auto o = run_estimator(k.oracle, p, k.encoder, b, kFs, k.encoder, kShortSettleS);
        if (o.m.std_rad < best) { best = o.m.std_rad; best_fn = fn > 0 ? fn : 100; }
    }
    return {best, best_fn, a.bounds["pcrb_rad"].get<double>(), a.m.std_rad, a.m, a.e->state()};
}

// Hidden (minutes under ASan+UBSan): run in the Release build's estimator.long entry.
TEST_CASE("ekf-auto told nothing, on 0.6 s captures scored from 0.1 s, tracks within 1.5x of the oracle or the PCRB",
          "[estimator][ekf-auto][accuracy][long][.long]") {
    for (const auto& k : short_suite()) {
        if (k.target <= 0) continue;  // a known miss: the table prints it
        for (std::uint64_t seed : {21, 22, 23, 24}) {
            const ShortRow r = measure_short(k, seed);
            INFO(k.name << " seed " << seed << ": ekf-auto std " << r.automatic << ", oracle " << r.oracle << " (fn " << r.oracle_fn
                        << " Hz), PCRB " << r.pcrb << " state " << r.state.dump());
            CHECK(r.m.slipped_samples == 0);
            CHECK(r.m.invalid_after_settle == 0);
            CHECK(r.automatic < k.target * std::max(r.oracle, r.pcrb));
        }
    }
}

// Prints the short table of docs/estimators.md: build/tests/fringe_tests "[ekf-auto-short-table]"
TEST_CASE("ekf-auto short-capture table", "[.ekf-auto-short-table]") {
    // FRINGE_SHORT_TABLE_ROWS=text: only the kinds whose name contains it
    const char* only = std::getenv("FRINGE_SHORT_TABLE_ROWS");
    std::printf("| kind | oracle (fn Hz) | PCRB | ekf-auto | ratio | worst ratio, seeds 21-24 | slipped | chosen fn mean/peak Hz | shape learnt s |\n");
    for (const auto& k : short_suite()) {
        if (only && k.name.find(only) == std::string::npos) continue;
        const ShortRow r = measure_short(k, 21);
        double worst = 0;
        long long slipped = 0;
        for (std::uint64_t seed = 21; seed <= 24; ++seed) {
            const ShortRow q = seed == 21 ? r : measure_short(k, seed);
            worst = std::max(worst, q.automatic / std::max(q.oracle, q.pcrb));
            slipped += static_cast<long long>(q.m.slipped_samples);
        }
        const auto& bw = r.state["bandwidth"];
        std::printf("| %s | %.3g (%g) | %.3g | %.3g | %.2f | %.2f | %lld | %.0f / %.0f | %s |\n", k.name.c_str(), r.oracle, r.oracle_fn, r.pcrb,
                    r.automatic, r.automatic / std::max(r.oracle, r.pcrb), worst, slipped, bw["mean_hz"].get<double>(),
                    bw["peak_hz"].get<double>(), r.state["shape_learnt_s"].dump().c_str());
        std::fflush(stdout);
    }
}

// u's random walk follows the variation seen (issue 28): at its floor on a shape that holds
// still (the paper signal), raised on a light source drifting +-6 % at 3 Hz, whose u moves by
// ~2/s; and the variation's points are not held back at constant speed (the fast drift within
// 1.5x from 0.1 s is the short table's check)
TEST_CASE("ekf-auto raises the variation's random walk only for a shape that varies", "[estimator][ekf-auto]") {
    double floor_q = 0;  // q_variation_per_s's default
    for (const auto& p : est::find("ekf-auto").params)
        if (p.name == "q_variation_per_s") floor_q = p.default_value.get<double>();
    REQUIRE(floor_q > 0);
    const auto n = static_cast<std::size_t>(kShortS * kFs);
    const auto paper = fixture_encoder("paper-duty1p6");
    const Block bp = generate(paper, constant_electrical(98.4, 1024), kFs, n, 31);
    auto a = run_estimator("ekf-auto", json::object(), std::nullopt, bp, kFs, paper, kShortSettleS);
    const json sp = a.e->state();
    INFO("paper: " << sp["variation"].dump());
    CHECK(sp["replays"].get<int>() >= 3);
    CHECK(sp["variation"]["q_per_s"].get<double>() == Approx(floor_q));
    auto drift = fixture_encoder("agc-drift");
    drift.noise.drift_amplitude = 0.06;
    drift.noise.drift_freq_hz = 3.0;
    const Block bd = generate(drift, constant_electrical(103.0, 1024), kFs, n, 31);
    auto d = run_estimator("ekf-auto", json::object(), std::nullopt, bd, kFs, drift, kShortSettleS);
    const json sd = d.e->state();
    INFO("drift: " << sd["variation"].dump());
    CHECK(sd["variation"]["q_per_s"].get<double>() > 10 * floor_q);
    CHECK(sd["variation"]["q_per_s"].get<double>() <= 30 * floor_q * (1 + 1e-12));
    CHECK(d.m.slipped_samples == 0);
}

TEST_CASE("ekf-auto learns the shape: the paper's 2nd harmonic, with the sin fundamental defining theta", "[estimator][ekf-auto]") {
    const auto kind = kind_named("paper-duty1p6");
    const Block b = generate(kind.encoder, kind.motion, kFs, 80000, 5);
    auto a = run_estimator("ekf-auto", json::object(), std::nullopt, b, kFs, kind.encoder, kSettleS);
    const json st = a.e->state();
    INFO(st.dump());
    CHECK(st["stage"] == "tracking");
    CHECK(st["order"].get<int>() >= 2);
    const auto& s = st["shape_sin"]["harmonics"];
    // MODEL.md 2.2: V_s = B1 sin(theta) - B2 cos(2 theta), B1 = 1.093 V, h2 = 2.52 %
    CHECK(s[0]["cos_v"].get<double>() == Approx(0.0).margin(1e-12));  // the convention, exactly
    CHECK(s[0]["sin_v"].get<double>() == Approx(1.093).epsilon(0.01));
    CHECK(s[1]["cos_v"].get<double>() == Approx(-0.0252 * 1.093).margin(1e-3));
    CHECK(std::fabs(s[1]["sin_v"].get<double>()) < 1e-3);
}

// Each identifier point averages the samples of a phase bin (up to 2 pi/points_per_cycle wide);
// the average of a sinusoid over a spread of phases is smaller than its value at the mean phase
// by var/2 (2.5e-5 relative at 256 points per cycle). Uncorrected, that made the learnt
// amplitude too small, and on light drift (whose variation carries a DC pedestal) a phase error.
TEST_CASE("ekf-auto learns the amplitude of a pure sinusoid without the bin-averaging bias", "[estimator][ekf-auto]") {
    auto enc = clean_ideal(1024);
    enc.noise.sigma_add_v = 1e-5;
    for (const double hz : {106.7, 10.0}) {  // ~940 and 10^4 samples per electrical cycle
        const Block b = generate(enc, constant_electrical(hz, 1024), kFs, hz > 50 ? 50000 : 200000, 8);
        auto a = run_estimator("ekf-auto", json::object(), std::nullopt, b, kFs, enc, kSettleS);
        const json st = a.e->state();
        INFO(hz << " Hz: " << st.dump());
        // V_s = sin(theta), V_c = cos(theta) (V_max = 1 V): amplitude 1 V, no offset
        const double as = std::hypot(st["shape_sin"]["harmonics"][0]["cos_v"].get<double>(), st["shape_sin"]["harmonics"][0]["sin_v"].get<double>());
        const double ac = std::hypot(st["shape_cos"]["harmonics"][0]["cos_v"].get<double>(), st["shape_cos"]["harmonics"][0]["sin_v"].get<double>());
        CHECK(std::fabs(as - 1.0) < 3e-6);
        CHECK(std::fabs(ac - 1.0) < 3e-6);
        CHECK(std::fabs(st["shape_sin"]["dc_v"].get<double>()) < 3e-6);
    }
}

TEST_CASE("ekf-auto holds its shape at standstill", "[estimator][ekf-auto]") {
    // move at ~107 Hz electrical for 0.6 s, stop (deceleration 0.07 s), then stand still
    auto enc = fixture_encoder("paper-duty1p6");
    MotionProfile m;
    m.kind = MotionKind::Trapezoid;
    m.velocity_rad_s = kTwoPi * 106.72358591248666 / 1024;
    m.accel_rad_s2 = 10.0;
    m.cruise_s = 0.6;
    const Block b = generate(enc, m, kFs, 120000, 6);
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = kFs;
    auto e = est::make("ekf-auto", cfg);
    const std::size_t half = 80000;  // at rest from ~0.73 s
    std::vector<double> th(b.size()), om(b.size());
    std::vector<std::uint8_t> v(b.size());
    e->process({std::span(b.sin_v).first(half), std::span(b.cos_v).first(half)},
               {std::span(th).first(half), std::span(om).first(half), std::span(v).first(half)});
    const json before = e->state();
    e->process({std::span(b.sin_v).subspan(half), std::span(b.cos_v).subspan(half)},
               {std::span(th).subspan(half), std::span(om).subspan(half), std::span(v).subspan(half)});
    const json after = e->state();
    INFO(before.dump() << "\n" << after.dump());
    CHECK(before["order"].get<int>() >= 2);
    CHECK(after["shape_sin"] == before["shape_sin"]);
    CHECK(after["shape_cos"] == before["shape_cos"]);
    CHECK(after["accepted_points"] == before["accepted_points"]);
    CHECK(after["loss_of_lock"]["events"] == 0);
    CHECK(v.back() == 1);
    // as good as the shape learnt in 0.6 s of motion (not yet converged to the bound: ~6e-3 rad)
    CHECK(std::fabs(th.back() - b.theta_rad.back()) < 0.02);
}

TEST_CASE("ekf-auto: no cycle slip in 10^7 samples of the paper's signal", "[estimator][ekf-auto][long][.long]") {
    const auto sc = load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/paper-duty1p6.json");
    Generator g(sc.encoder, sc.motion, sc.sample_rate_hz, 99);
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = sc.sample_rate_hz;
    auto e = est::make("ekf-auto", cfg);
    Scorer s(kSettleS);
    constexpr std::size_t kBlock = 1 << 20;
    Block b;
    std::vector<double> th(kBlock), om(kBlock);
    std::vector<std::uint8_t> v(kBlock);
    for (std::uint64_t k = 0; k < 10'000'000;) {
        const std::size_t n = std::min<std::uint64_t>(kBlock, 10'000'000 - k);
        b.resize(n, false);
        th.resize(n); om.resize(n); v.resize(n);
        g.generate(k, b);
        e->process({b.sin_v, b.cos_v}, {th, om, v});
        s.add(n, b.t_s.data(), b.theta_rad.data(), b.omega_rad_s.data(), th.data(), om.data(), v.data());
        k += n;
    }
    const auto m = s.finish();
    INFO(e->state().dump());
    CHECK(m.scored > 9'900'000);
    CHECK(m.slipped_samples == 0);
    CHECK(m.invalid_after_settle == 0);
    CHECK(e->state()["loss_of_lock"]["events"] == 0);
    CHECK(m.std_rad < 4e-5);
}

TEST_CASE("ekf-auto gives no valid output without a signal that moves, and says why", "[estimator][ekf-auto]") {
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = kFs;
    for (const auto& [name, s_v, c_v] : {std::tuple{"zeros", 0.0, 0.0}, std::tuple{"constant", 0.5, 0.3}}) {
        auto e = est::make("ekf-auto", cfg);
        const std::size_t n = 20000;
        std::vector<double> s(n, s_v), c(n, c_v), th(n), om(n);
        std::vector<std::uint8_t> v(n, 1);
        e->process({s, c}, {th, om, v});
        INFO(name << ": " << e->state().dump());
        CHECK(std::count(v.begin(), v.end(), 1) == 0);
        CHECK(e->state().contains("message"));
        const auto R = e->state()["noise_cov_v2"];
        CHECK(R[0].get<double>() > 0);
        CHECK(R[2].get<double>() > 0);
    }
    SECTION("noise only: nothing valid, and the message says it never locked") {
        auto e = est::make("ekf-auto", cfg);
        const std::size_t n = 50000;
        std::mt19937_64 rng(11);
        std::normal_distribution<double> g(0.0, 0.01);  // V
        std::vector<double> s(n), c(n), th(n), om(n);
        for (std::size_t k = 0; k < n; ++k) { s[k] = g(rng); c[k] = g(rng); }
        std::vector<std::uint8_t> v(n, 1);
        e->process({s, c}, {th, om, v});
        INFO(e->state().dump());
        CHECK(std::count(v.begin(), v.end(), 1) < static_cast<long>(n / 100));
        REQUIRE(e->state()["message"].is_string());
        CHECK(e->state()["message"].get<std::string>().find("no lock") != std::string::npos);
    }
}

TEST_CASE("ekf-auto ignores a profile unless told to start from it, and then keeps lock", "[estimator][ekf-auto]") {
    const auto kind = kind_named("paper-duty1p6");
    const Block b = generate(kind.encoder, kind.motion, kFs, 60000, 7);
    // the profile comes with the capture: ignored (told nothing), output invalid until learnt
    auto plain = run_estimator("ekf-auto", json::object(), kind.encoder, b, kFs, kind.encoder, kSettleS);
    CHECK(plain.e->state()["told_profile"] == false);
    CHECK(std::find(plain.valid.begin() + 200, plain.valid.begin() + 400, 1) == plain.valid.begin() + 400);
    // started from it: valid from acquisition on, no loss of lock, at the bound
    auto told = run_estimator("ekf-auto", {{"start_from_profile", true}}, kind.encoder, b, kFs, kind.encoder, kSettleS);
    INFO(told.e->state().dump());
    CHECK(told.e->state()["told_profile"] == true);
    CHECK(told.e->state()["loss_of_lock"]["events"] == 0);
    CHECK(told.valid[300] == 1);
    CHECK(told.m.std_rad < 1.5 * told.bounds["pcrb_rad"].get<double>());
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = kFs;
    cfg.params = {{"start_from_profile", true}};
    CHECK_THROWS_WITH(est::make("ekf-auto", cfg), Catch::Contains("params.start_from_profile"));
    cfg.params = {{"learn", false}};
    CHECK_THROWS_WITH(est::make("ekf-auto", cfg), Catch::Contains("params.learn"));
}

TEST_CASE("ekf-auto needs no parameters at a 1 kHz sample rate either", "[estimator][ekf-auto]") {
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = 1000;
    auto e = est::make("ekf-auto", cfg);  // the 100 Hz default would be too high: fs/(8 pi)
    REQUIRE(e->prior());
    CHECK(e->prior()->natural_freq_hz == Approx(1000 / (8 * 3.14159265358979)).epsilon(1e-9));
    cfg.params = {{"natural_freq_hz", 100.0}};  // given, it is not changed: an error
    CHECK_THROWS_WITH(est::make("ekf-auto", cfg), Catch::Contains("params.natural_freq_hz"));
}

// Found by a hostile trial: one glitch sample (5 V, 1e6, 1e300) widened the loss-of-lock
// monitor's own min/max frame for good, and ekf-auto then lost lock 237 times and was 9 % valid.
TEST_CASE("ekf-auto: a single glitch sample is an outlier, not a loss of lock", "[estimator][ekf-auto]") {
    const auto kind = kind_named("paper-duty1p6");
    for (const double glitch_v : {5.0, 1e6, 1e300}) {
        Block b = generate(kind.encoder, kind.motion, kFs, 60000, 9);
        b.sin_v[30000] = glitch_v;
        auto a = run_estimator("ekf-auto", json::object(), std::nullopt, b, kFs, kind.encoder, kSettleS);
        const json st = a.e->state();
        INFO(glitch_v << " V: " << st.dump());
        CHECK(st["loss_of_lock"]["events"] == 0);
        CHECK(st["outlier_samples"] == 1);
        CHECK(a.valid[30000] == 0);
        CHECK(a.m.invalid_after_settle <= 1);
        CHECK(a.m.slipped_samples == 0);
        CHECK(a.m.std_rad < 1.5 * a.bounds["pcrb_rad"].get<double>());
    }
}

// Found by a second hostile trial: glitches from the first sample on. 0.1 % of samples at 5 V
// were learnt into R and the shape before the outlier gate was on (then no glitch looked like
// one: 1.3e-2 rad, valid 100 %); 1e300 every 100 samples spoiled the acquisition's amplitude
// (never learnt); a 1.3 V spike every 100 (or 5 V every 300) slipped the loss-of-lock
// reference's unwrap a turn, and the re-anchored tracker ran a turn off, marked valid.
TEST_CASE("ekf-auto: repeated glitches from the start are outliers: no slip, at the bound", "[estimator][ekf-auto]") {
    const auto kind = kind_named("paper-duty1p6");
    struct Case { std::size_t every; double sin_v; double max_ratio; };
    for (const Case c : {Case{1000, 5.0, 1.5}, Case{300, 5.0, 1.5}, Case{100, 1e300, 1.5}, Case{100, 1.3, 8.0}}) {
        Block b = generate(kind.encoder, kind.motion, kFs, 100000, 13);
        for (std::size_t i = c.every; i < b.size(); i += c.every) b.sin_v[i] = c.sin_v;
        auto a = run_estimator("ekf-auto", json::object(), std::nullopt, b, kFs, kind.encoder, 0.5);
        const json st = a.e->state();
        INFO("every " << c.every << " at " << c.sin_v << " V: std " << a.m.std_rad << " rad, " << st.dump().substr(0, 400));
        CHECK(a.m.slipped_samples == 0);
        CHECK(st["loss_of_lock"]["events"] == 0);
        CHECK(st["outlier_samples"].get<long long>() > 0);
        CHECK(a.m.scored > 45000);
        // the 1.3 V spikes inside the signal's range are not all outliers: they cost accuracy, not a turn
        CHECK(a.m.std_rad < c.max_ratio * a.bounds["pcrb_rad"].get<double>());
    }
}

// A capture that tracked and then froze (an ADC stuck from 40 % on) says so, not that it never moved.
TEST_CASE("ekf-auto: a signal that freezes after tracking says it has not moved since re-acquiring", "[estimator][ekf-auto]") {
    const auto kind = kind_named("paper-duty1p6");
    Block b = generate(kind.encoder, kind.motion, kFs, 100000, 15);
    for (std::size_t i = 40000; i < b.size(); ++i) { b.sin_v[i] = b.sin_v[40000]; b.cos_v[i] = b.cos_v[40000]; }
    auto a = run_estimator("ekf-auto", json::object(), std::nullopt, b, kFs, kind.encoder, 0.0);
    const json st = a.e->state();
    INFO(st.dump().substr(0, 600));
    CHECK(std::count(a.valid.begin() + 30000, a.valid.begin() + 39000, 1) > 8000);  // it tracked
    CHECK(std::count(a.valid.begin() + 45000, a.valid.end(), 1) == 0);            // nothing valid once frozen
    CHECK(a.m.slipped_samples == 0);
    REQUIRE(st["message"].is_string());
    CHECK_THAT(st["message"].get<std::string>(), Catch::Contains("since it last re-acquired"));
}

// ... and a signal whose amplitude jumps (x10) is acquired afresh, not tracked with the old shape
TEST_CASE("ekf-auto: an amplitude jump is a signal change: re-acquired, then tracked", "[estimator][ekf-auto]") {
    const auto kind = kind_named("paper-duty1p6");
    Block b = generate(kind.encoder, kind.motion, kFs, 120000, 10);
    for (std::size_t i = 30000; i < b.size(); ++i) {
        b.sin_v[i] *= 10;
        b.cos_v[i] *= 10;
    }
    auto a = run_estimator("ekf-auto", json::object(), std::nullopt, b, kFs, kind.encoder, 0.9);  // scored from 0.9 s
    const json st = a.e->state();
    INFO(st.dump());
    CHECK(st["signal_changes"] == 1);
    CHECK(st["loss_of_lock"]["events"] == 0);
    CHECK(std::count(a.valid.begin() + 30000, a.valid.begin() + 30032, 1) == 0);  // the run that told it
    CHECK(a.m.slipped_samples == 0);
    CHECK(a.m.invalid_after_settle == 0);
    // signal and noise scaled together: the same bound, reached with the new shape
    CHECK(a.m.std_rad < 1.5 * a.bounds["pcrb_rad"].get<double>());
}

}  // namespace test_ekf_auto_cpp
