// Self-calibration, AGC, kappa tracking, the closed loop, the external adapter, block
// partitions and covariance health.
#include "estimator_helpers.hpp"

#include "estimator/ekf.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/fastmath.hpp"

#include <catch2/catch.hpp>

#include <chrono>
#include <random>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_estimators_more_cpp {

using namespace fringe;
using namespace fringe::test;
using nlohmann::json;

namespace {
constexpr double kFs = 100e3;
EncoderProfile paper() {
    return load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/paper-duty1p6.json").encoder;
}
}  // namespace

TEST_CASE("ekf-selfcal needs no distortion parameters", "[estimator][selfcal]") {
    auto enc = clean_ideal(1024);
    enc.vmax_v = 0.8;
    enc.noise.sigma_add_v = 5e-4;
    enc.lissajous = {0.05, 0.04, -0.03, 0.04};
    const Block b = generate(enc, constant_electrical(106.7, 1024), kFs, 200000, 21);
    auto plain = run_estimator("atan2", json::object(), std::nullopt, b, kFs, enc, 1.0);
    auto self = run_estimator("ekf-selfcal", json::object(), std::nullopt, b, kFs, enc, 1.0);
    INFO("atan2 uncalibrated rms " << plain.m.rms_rad << ", ekf-selfcal rms " << self.m.rms_rad << ", eff " << self.efficiency());
    const json st = self.e->state();
    CHECK(st["offset_sin_v"].get<double>() == Approx(0.04).margin(2e-3));
    CHECK(st["offset_cos_v"].get<double>() == Approx(-0.03).margin(2e-3));
    CHECK(st["gain_mismatch"].get<double>() == Approx(0.05).margin(5e-3));
    CHECK(st["quadrature_error_rad"].get<double>() == Approx(0.04).margin(5e-3));
    CHECK(plain.m.rms_rad > 0.03);
    CHECK(self.efficiency() > 0.8);
    CHECK(self.efficiency() < 1.25);
}

TEST_CASE("AGC follows a drifting light source (Fig. 14)", "[estimator][agc]") {
    auto enc = paper();
    enc.noise.drift_amplitude = 0.03;  // +-3 % at 2 Hz
    enc.noise.drift_freq_hz = 2.0;
    const Block b = generate(enc, constant_electrical(106.7236, enc.lines_per_rev), kFs, 100000, 8);
    auto fixed = run_estimator("ekf-diffraction", json::object(), enc, b, kFs, enc, 0.1);
    auto agc = run_estimator("ekf-diffraction", {{"agc", true}, {"q_gain_per_s", 1e-2}}, enc, b, kFs, enc, 0.1);
    INFO("drift: fixed gain rms " << fixed.m.rms_rad << ", agc rms " << agc.m.rms_rad << " gain " << agc.e->state()["gain"]);
    CHECK(agc.m.rms_rad < 0.2 * fixed.m.rms_rad);
    CHECK(agc.m.rms_rad < 3 * agc.bounds["pcrb_rad"].get<double>());
}

TEST_CASE("kappa state follows gap run-out", "[estimator][kappa]") {
    auto enc = paper();
    enc.lines_per_rev = 16;  // a revolution every 0.15 s, so kappa runs 1.0..1.115 quickly
    enc.gap_d1_cm = 0.747;
    enc.gap_d2_cm = 0.670;
    const Block b = generate(enc, constant_electrical(106.7236, 16), kFs, 100000, 2);
    auto fixed = run_estimator("ekf-diffraction", json::object(), enc, b, kFs, enc, 0.1);
    auto tracked = run_estimator("ekf-diffraction", {{"track_kappa", true}, {"q_kappa_per_s", 1e-2}}, enc, b, kFs, enc, 0.1);
    INFO("run-out: fixed kappa rms " << fixed.m.rms_rad << ", kappa state rms " << tracked.m.rms_rad);
    CHECK(tracked.m.rms_rad < 0.3 * fixed.m.rms_rad);
    CHECK(tracked.m.rms_rad < 1.5 * tracked.bounds["pcrb_rad"].get<double>());
}

TEST_CASE("closed loop: (8+8)-bit equals 16-bit open loop within 20 %, auto-ranging acquires", "[estimator][closed-loop]") {
    auto enc = paper();
    enc.noise.sigma_add_v = 5e-5;
    enc.noise.sigma_gain = 0;
    auto analog = enc;
    analog.adc.bits = 0;  // the closed loop digitises the analog signal itself
    auto open16 = enc;
    open16.adc.bits = 16;
    const auto motion = constant_electrical(106.7236, enc.lines_per_rev);
    const Block a = generate(analog, motion, kFs, 100000, 13);
    const Block o = generate(open16, motion, kFs, 100000, 13);
    auto open = run_estimator("ekf-diffraction", json::object(), open16, o, kFs, open16, 0.1);
    auto closed = run_estimator("closed-loop", {{"adc_bits", 8}, {"gain_bits", 8}, {"dac_bits", 10}}, analog, a, kFs, open16, 0.1);
    auto closed10 = run_estimator("closed-loop", {{"adc_bits", 10}, {"gain_bits", 0}, {"dac_bits", 10}}, analog, a, kFs, open16, 0.1);
    INFO("open 16 bit " << open.m.rms_rad << ", closed (8+8)+10 " << closed.m.rms_rad << ", closed (0+10)+10 " << closed10.m.rms_rad
         << " first N=8 at sample " << closed.e->state()["first_sample_at_max_gain"]);
    CHECK(closed.m.rms_rad == Approx(open.m.rms_rad).epsilon(0.2));
    CHECK(closed.e->state()["gain_bits_final"] == 8);
    CHECK(closed.e->state()["first_sample_at_max_gain"].get<long long>() < 10000);
    CHECK(closed10.m.rms_rad > 3 * closed.m.rms_rad);  // 10 bits is quantisation-limited
    // Without auto-ranging, N = 8 from the start saturates during acquisition
    auto fixed = run_estimator("closed-loop", {{"adc_bits", 8}, {"gain_bits", 8}, {"auto_range", false}}, analog, a, kFs, open16, 0.1);
    CHECK(fixed.e->state()["clipped_samples"].get<long long>() > 0);
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = kFs;
    cfg.encoder = analog;
    cfg.params = {{"gain_bits", 10}, {"dac_bits", 10}};
    CHECK_THROWS_WITH(est::make("closed-loop", cfg), Catch::Contains("params.gain_bits"));
}

TEST_CASE("output does not depend on the block partition", "[estimator][blocks]") {
    const auto enc = paper();
    const Block b = generate(enc, constant_electrical(106.7236, enc.lines_per_rev), kFs, 30000, 4);
    const std::string name = GENERATE(as<std::string>{}, "atan2", "atan2-ellipse", "pll2", "ekf-ideal", "ekf-diffraction",
                                      "ekf-sin-only", "ekf-parallel", "ekf-rectified", "ekf-selfcal", "closed-loop", "ekf-auto");
    INFO(name);
    const json params = name == "atan2-ellipse" ? json{{"mode", "recursive"}} : json::object();
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = kFs;
    cfg.encoder = enc;
    cfg.params = params;
    auto one = est::make(name, cfg);
    auto parts = est::make(name, cfg);
    const std::size_t n = b.size();
    std::vector<double> t1(n), w1(n), t2(n), w2(n);
    std::vector<std::uint8_t> v1(n), v2(n);
    one->process({b.sin_v, b.cos_v}, {t1, w1, v1});
    std::mt19937 rng(3);
    for (std::size_t i = 0; i < n;) {
        const std::size_t m = std::min<std::size_t>(n - i, 1 + rng() % 3000);
        parts->process({std::span(b.sin_v).subspan(i, m), std::span(b.cos_v).subspan(i, m)},
                       {std::span(t2).subspan(i, m), std::span(w2).subspan(i, m), std::span(v2).subspan(i, m)});
        i += m;
    }
    CHECK(t1 == t2);
    CHECK(w1 == w2);
    CHECK(v1 == v2);
}

TEST_CASE("non-finite samples are skipped, not propagated", "[estimator][nan]") {
    const auto enc = paper();
    Block b = generate(enc, constant_electrical(106.7236, enc.lines_per_rev), kFs, 30000, 4);
    for (std::size_t i = 20000; i < 20010; ++i) b.sin_v[i] = std::nan("");
    auto r = run_estimator("ekf-diffraction", json::object(), enc, b, kFs, enc, 0.1);
    CHECK(r.e->state()["nonfinite_samples"] == 10);
    CHECK(r.valid[20005] == 0);
    CHECK(r.m.invalid_after_settle == 10);
    CHECK(std::isfinite(r.m.rms_rad));
    CHECK(r.m.rms_rad < 1e-4);
}

TEST_CASE("external: a child process over the text and binary protocols", "[estimator][external]") {
    const auto enc = paper();
    const Block b = generate(enc, constant_electrical(106.7236, enc.lines_per_rev), kFs, 50000, 6);
    const std::string helper = FRINGE_EXTERNAL_HELPER;
    const std::string proto = GENERATE(as<std::string>{}, "text", "binary");
    INFO(proto);
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = kFs;
    cfg.params = {{"command", helper}, {"protocol", proto}};
    auto ext = est::make("external", cfg);
    cfg.params = json::object();
    auto ref = est::make("atan2", cfg);  // no profile: zero offsets, unit amplitudes, same as the helper
    const std::size_t n = b.size();
    std::vector<double> t1(n), w1(n), t2(n), w2(n);
    std::vector<std::uint8_t> v1(n), v2(n);
    for (std::size_t i = 0; i < n; i += 7000) {  // several blocks through one child
        const std::size_t m = std::min<std::size_t>(7000, n - i);
        ext->process({std::span(b.sin_v).subspan(i, m), std::span(b.cos_v).subspan(i, m)},
                     {std::span(t1).subspan(i, m), std::span(w1).subspan(i, m), std::span(v1).subspan(i, m)});
    }
    ref->process({b.sin_v, b.cos_v}, {t2, w2, v2});
    double worst = 0;
    for (std::size_t i = 0; i < n; ++i) worst = std::max(worst, std::fabs(t1[i] - t2[i]));
    CHECK(worst < 1e-9);
    CHECK(v1[n - 1] == 1);
}

TEST_CASE("external: a crashing, silent or garbled child ends with a clear error, not a hang", "[estimator][external]") {
    const Block b = generate(paper(), constant_electrical(106.7236, 1024), kFs, 5000, 6);
    std::vector<double> th(b.size()), om(b.size());
    std::vector<std::uint8_t> v(b.size());
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = kFs;
    auto run = [&](const json& params) {
        cfg.params = params;
        auto e = est::make("external", cfg);
        e->process({b.sin_v, b.cos_v}, {th, om, v});
    };
    const std::string helper = FRINGE_EXTERNAL_HELPER;
    const auto t0 = std::chrono::steady_clock::now();
    CHECK_THROWS_WITH(run({{"command", helper + " --crash-after 1000"}}),
                      Catch::Contains("Aborted") && Catch::Contains("after 1000 estimates"));
    CHECK_THROWS_WITH(run({{"command", "exit 3"}}), Catch::Contains("status 3"));
    CHECK_THROWS_WITH(run({{"command", "sleep 30"}, {"timeout_s", 0.5}}), Catch::Contains("no output for"));
    CHECK_THROWS_WITH(run({{"command", "yes hello"}}), Catch::Contains("is not 'theta_rad omega_rad_s valid'"));
    CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(20));
    cfg.params = json::object();
    CHECK_THROWS_WITH(est::make("external", cfg), Catch::Contains("params.command"));
}

TEST_CASE("EKF covariance stays symmetric positive definite over 10^8 samples", "[estimator][long][.long]") {
    // Every optional state on, on the paper's signal with drift and gap run-out.
    auto enc = paper();
    enc.noise.drift_amplitude = 0.02;
    enc.noise.drift_freq_hz = 1.0;
    enc.lines_per_rev = 64;
    enc.gap_d2_cm = 0.670;
    Generator g(enc, constant_electrical(106.7236, 64), kFs, 77);
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = kFs;
    cfg.encoder = enc;
    cfg.params = {{"agc", true}, {"track_kappa", true}, {"track_offsets", true}, {"kinematics", "ca"}};
    auto e = est::make("ekf-diffraction", cfg);
    constexpr std::size_t kBlock = 1 << 20;
    Block b;
    b.resize(kBlock, false);
    std::vector<double> th(kBlock), om(kBlock);
    std::vector<std::uint8_t> v(kBlock);
    std::uint64_t bad = 0, skipped_before = 0;
    for (std::uint64_t k = 0; k < 100'000'000; k += kBlock) {
        g.generate(k, b);
        e->process({b.sin_v, b.cos_v}, {th, om, v});
        const json st = e->state();
        if (!st["covariance_ok"].get<bool>()) ++bad;
        skipped_before = st["skipped_updates"].get<std::uint64_t>();
    }
    CHECK(bad == 0);
    CHECK(skipped_before == 0);
}

TEST_CASE("no cycle slip in 10^7 samples of the paper's signal at 937 samples/cycle", "[estimator][long][.long]") {
    const auto sc = load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/paper-duty1p6.json");
    Generator g(sc.encoder, sc.motion, sc.sample_rate_hz, 99);
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = sc.sample_rate_hz;
    cfg.encoder = sc.encoder;
    auto e = est::make("ekf-diffraction", cfg);
    Scorer s(0.1);
    constexpr std::size_t kBlock = 1 << 20;
    Block b;
    b.resize(kBlock, false);
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
    CHECK(m.scored > 9'900'000);
    CHECK(m.slipped_samples == 0);
    CHECK(m.max_abs_rad < 2e-4);
}

}  // namespace test_estimators_more_cpp
