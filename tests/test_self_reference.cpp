// Interpolation error without truth (server/analysis/self_reference.hpp, docs/self-reference.md):
// closed forms on synthetic signals, then the self-referenced figures of atan2, pll2 and
// ekf-ideal against the truth-scored ones on runs of several kinds, and a capture without truth.
#include "helpers.hpp"

#include "drivers/capture_file.hpp"
#include "server/analysis/self_reference.hpp"
#include "server/engine/capture_run.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/report/report_formats.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/generator.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <random>
#include <set>
#include <vector>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_self_reference_cpp {

using namespace fringe;
using nlohmann::json;
using test::TempDir;

namespace {

// Signals of a smooth motion theta(t) = w t + a t^2 / 2 (rad) with white noise sigma_v on each
// channel, amplitude 1 V, and an "estimator" that is the signals' own unwrapped phase plus a
// chosen periodic error: its error against the true phase is that error plus the noise's
// phase, sigma_v / 1 V rad rms (closed form).
struct Synthetic {
    std::vector<double> t, s, c, theta_hat, theta;
    std::vector<std::uint8_t> valid;
};

Synthetic synthetic(std::size_t n, double fs, double w_rad_s, double a_rad_s2, double sigma_v, double a1, double b3, double lag_s = 0,
                    unsigned seed = 5) {
    Synthetic x;
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> noise(0.0, sigma_v);
    double unwrapped = 0, last = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const double t = static_cast<double>(i) / fs;
        const double th = w_rad_s * t + 0.5 * a_rad_s2 * t * t;
        const double sv = std::sin(th) + noise(rng), cv = std::cos(th) + noise(rng);
        const double wr = std::atan2(sv, cv);
        if (i == 0) unwrapped = wr;
        else {
            double d = wr - last;
            d -= kTwoPi * std::round(d / kTwoPi);
            unwrapped += d;
        }
        last = wr;
        // A tracker late by lag_s reads the phase of lag_s ago (its error -omega(t) lag_s).
        const double late = lag_s > 0 ? -(w_rad_s + a_rad_s2 * t) * lag_s : 0.0;
        x.t.push_back(t);
        x.s.push_back(sv);
        x.c.push_back(cv);
        x.theta.push_back(th);
        x.theta_hat.push_back(unwrapped + late + a1 * std::cos(th) + b3 * std::sin(3 * th));
        x.valid.push_back(1);
    }
    return x;
}

SelfReferenceResult analyse(const Synthetic& x, std::size_t block = 4096, SelfReferenceOptions o = {}) {
    SelfReference sr(o);
    for (std::size_t i = 0; i < x.t.size(); i += block) {
        const std::size_t m = std::min(block, x.t.size() - i);
        sr.add(m, &x.t[i], &x.s[i], &x.c[i], &x.theta_hat[i], &x.valid[i]);
    }
    return sr.finish();
}

}  // namespace

TEST_CASE("self-reference: harmonics and rms of a known periodic error plus the noise's phase", "[selfref]") {
    const double sigma_v = 1e-3, a1 = 2e-3, b3 = 1e-3;
    const auto x = synthetic(200000, 100000, kTwoPi * 150, kTwoPi * 40, sigma_v, a1, b3);
    const auto r = analyse(x);
    REQUIRE(r.measured);
    CHECK(r.windows >= 15);
    REQUIRE(r.harmonics.size() == 8);
    // a1 cos(theta): amplitude a1, phase 0; b3 sin(3 theta): amplitude b3, phase pi/2.
    CHECK(std::fabs(r.harmonics[0].amplitude_rad - a1) < 4 * r.harmonics[0].u_rad + 1e-6);
    CHECK(std::fabs(r.harmonics[0].phase_rad) < 0.02);
    CHECK(std::fabs(r.harmonics[2].amplitude_rad - b3) < 4 * r.harmonics[2].u_rad + 1e-6);
    CHECK(std::fabs(r.harmonics[2].phase_rad - kPi / 2) < 0.02);
    for (int k : {1, 3, 4, 5, 6, 7}) CHECK(r.harmonics[static_cast<std::size_t>(k)].amplitude_rad < 4 * r.harmonics[static_cast<std::size_t>(k)].u_rad + 2e-6);
    // rms about the mean: sqrt(a1^2/2 + b3^2/2 + (sigma_v / 1 V)^2).
    const double expect = std::sqrt(a1 * a1 / 2 + b3 * b3 / 2 + sigma_v * sigma_v);
    INFO("rms " << r.rms_rad << " +- " << r.rms_u_rad << " expected " << expect);
    CHECK(std::fabs(r.rms_rad - expect) < std::max(4 * r.rms_u_rad, 0.02 * expect));
    CHECK(std::fabs(r.residual_rms_rad - sigma_v) < 0.03 * sigma_v);
    CHECK(r.rms_u_rad > 0);
    CHECK(r.rms_u_rad < 0.05 * r.rms_rad);
    // The reference's own noise: about sigma sqrt(6 / n_window), far below the noise.
    CHECK(r.reference_noise_rad > 0);
    CHECK(r.reference_noise_rad < 0.1 * sigma_v);
    CHECK(std::fabs(r.reference_residual_rms_rad - sigma_v) < 0.05 * sigma_v);
}

TEST_CASE("self-reference: the mean is not observable, the block size does not matter", "[selfref]") {
    auto x = synthetic(120000, 100000, kTwoPi * 200, 0, 5e-4, 1e-3, 0);
    const auto r = analyse(x, 4096);
    for (auto& v : x.theta_hat) v += 0.3;  // a constant offset: invisible
    const auto shifted = analyse(x, 777);
    REQUIRE(r.measured);
    REQUIRE(shifted.measured);
    CHECK(shifted.rms_rad == Approx(r.rms_rad).epsilon(1e-9));
    CHECK(shifted.harmonics[0].amplitude_rad == Approx(r.harmonics[0].amplitude_rad).epsilon(1e-9));
    CHECK(shifted.mean_vs_reference_rad - r.mean_vs_reference_rad == Approx(0.3).margin(1e-9));
    // An origin about pi away, with the error's mean wandering across +-pi between windows: no
    // window may be put a turn away from the others.
    for (std::size_t i = 0; i < x.theta_hat.size(); ++i)
        x.theta_hat[i] += kPi - 0.3 + 0.05 * std::sin(kTwoPi * 3.0 * x.t[i]);
    const auto near_pi = analyse(x, 4096);
    REQUIRE(near_pi.measured);
    CHECK(near_pi.rms_rad < 0.1);
}

TEST_CASE("self-reference: a tracker's lag that changes with the speed is seen (the reference has none)", "[selfref]") {
    // Error -omega(t) d with omega = w + a t: over the windows used its spread about the mean is
    // a d T / sqrt(12) for a uniform sweep of t over T (closed form for a ramp).
    const double fs = 100000, w = kTwoPi * 100, acc = kTwoPi * 400, d = 2e-4;
    const std::size_t n = 100000;
    const auto x = synthetic(n, fs, w, acc, 1e-5, 0, 0, d);
    const auto r = analyse(x);
    REQUIRE(r.measured);
    const double span_s = static_cast<double>(r.samples) / fs;
    const double expect = acc * d * span_s / std::sqrt(12.0);
    INFO("rms " << r.rms_rad << " expected about " << expect << " over " << span_s << " s");
    CHECK(r.rms_rad == Approx(expect).epsilon(0.05));
}

TEST_CASE("self-reference: no motion, gaps, NaN and a short run are not measured, with the reason", "[selfref]") {
    SECTION("standing still") {
        auto x = synthetic(50000, 100000, 0, 0, 1e-3, 0, 0);
        const auto r = analyse(x);
        CHECK_FALSE(r.measured);
        CHECK_THAT(r.why_not, Catch::Contains("no window"));
        CHECK(r.windows == 0);
        CHECK_FALSE(r.windows_skipped.empty());
        const json j = to_json(r);
        CHECK(j["measured"] == false);
        CHECK_FALSE(j.contains("rms_rad"));  // never a 0 that could pass a limit
    }
    SECTION("every other sample invalid: no window spans a gap") {
        auto x = synthetic(50000, 100000, kTwoPi * 200, 0, 1e-3, 0, 0);
        for (std::size_t i = 0; i < x.valid.size(); i += 2) x.valid[i] = 0;
        const auto r = analyse(x);
        CHECK_FALSE(r.measured);
        CHECK_THAT(r.why_not, Catch::Contains("no window") && Catch::Contains("an invalid estimate is a gap"));
    }
    SECTION("every sample invalid: the reason is the estimator's, not the motion's") {
        auto x = synthetic(50000, 100000, kTwoPi * 200, 0, 1e-3, 0, 0);
        std::fill(x.valid.begin(), x.valid.end(), std::uint8_t{0});
        const auto r = analyse(x);
        CHECK_FALSE(r.measured);
        CHECK_THAT(r.why_not, Catch::Contains("the estimator marked all") && Catch::Contains("invalid"));
    }
    SECTION("NaN outputs end windows; the rest is measured") {
        auto x = synthetic(200000, 100000, kTwoPi * 200, 0, 1e-3, 1e-3, 0);
        for (std::size_t i = 50000; i < 50100; ++i) x.theta_hat[i] = std::nan("");
        x.s[120000] = std::numeric_limits<double>::infinity();
        const auto r = analyse(x);
        REQUIRE(r.measured);
        CHECK(r.samples < 200000 - 100);
        CHECK(r.harmonics[0].amplitude_rad == Approx(1e-3).margin(4 * r.harmonics[0].u_rad + 1e-6));
    }
}

namespace {
json run_kind(const std::string& kind) {
    json enc = std::string(FRINGE_SOURCE_DIR) + "/fixtures/encoders/ideal.json";
    json motion = {{"kind", "constant"}, {"electrical_freq_hz", 180.0}};
    std::string device = "loopback:?dac_bits=16&adc_bits=16";
    if (kind == "paper") enc = std::string(FRINGE_SOURCE_DIR) + "/fixtures/encoders/paper-d2-analog.json";
    if (kind == "lissajous")
        enc = {{"name", "lissajous"}, {"model", "ideal"}, {"lines_per_rev", 1024}, {"vmax_v", 1.0}, {"noise", {{"sigma_add_v", 3e-4}}},
               {"lissajous", {{"gain_mismatch", 0.03}, {"offset_sin_v", -0.01}, {"offset_cos_v", 0.007}, {"quadrature_error_rad", 0.015}}}};
    if (kind == "adc10") device = "loopback:?dac_bits=16&adc_bits=10";
    if (kind == "accelerating") motion = {{"kind", "ramp"}, {"velocity_rad_s", 0.4}, {"accel_rad_s2", 4.0}};
    if (kind == "reversals") motion = {{"kind", "sine"}, {"amplitude_rad", 0.5}, {"freq_hz", 0.3}};
    const json j{{"name", "selfref-" + kind}, {"encoder", enc}, {"motion", motion}, {"sample_rate_hz", 100000}, {"duration_s", 1.0},
                 {"settle_s", 0.05}, {"seed", 23}, {"device", device}, {"scoring", {{"self_reference", true}}},
                 {"estimators", json::array({json{{"name", "atan2"}}, json{{"name", "pll2"}}, json{{"name", "ekf-ideal"}}})}};
    return execute_run(scenario_from_json(j, FRINGE_SOURCE_DIR "/fixtures/scenarios"));
}
}  // namespace

TEST_CASE("self-reference: agrees with the truth-scored error on generated runs of several kinds", "[selfref][run]") {
    for (const std::string kind : {"paper", "lissajous", "adc10", "accelerating", "reversals"}) {
        const json r = run_kind(kind);
        REQUIRE(r["status"] == "done");
        for (const auto& e : r["estimators"]) {
            INFO(kind << " " << e["label"]);
            const json& sr = e["analysers"]["self_reference"];
            REQUIRE(sr["measured"] == true);
            CHECK(sr["self_referenced"] == true);
            const double truth = e["metrics"]["std"]["rad"].get<double>();
            const double self = sr["rms_rad"].get<double>(), u = sr["rms_u_rad"].get<double>();
            INFO("truth std " << truth << " self-referenced " << self << " +- " << u);
            CHECK(std::fabs(self - truth) <= std::max(0.1 * truth, 2 * u));
            for (int k = 1; k <= 4; ++k) {
                double truth_k = 0, truth_phase = 0;
                for (const auto& h : e["metrics"]["harmonics"])
                    if (h["order"] == k) {
                        truth_k = h["amplitude"]["rad"].get<double>();
                        truth_phase = h["phase_rad"].get<double>();
                    }
                const json& hk = sr["harmonics"][static_cast<std::size_t>(k - 1)];
                INFO(k << "x truth " << truth_k << " self-referenced " << hk["amplitude_rad"] << " +- " << hk["u_rad"]);
                CHECK(std::fabs(hk["amplitude_rad"].get<double>() - truth_k) <= std::max(0.1 * truth_k, 3 * hk["u_rad"].get<double>()));
                // Where a harmonic stands well above its uncertainty, its phase is the truth's too:
                // the error curve against the electrical angle (the HTML's plot-self-reference) is the truth's.
                if (truth_k > 20 * hk["u_rad"].get<double>()) {
                    const double d = std::remainder(hk["phase_rad"].get<double>() - truth_phase, kTwoPi);
                    INFO(k << "x phase truth " << truth_phase << " self-referenced " << hk["phase_rad"]);
                    CHECK(std::fabs(d) <= std::max(0.1, 5 * hk["u_rad"].get<double>() / truth_k));
                }
            }
        }
    }
}

namespace {
// The paper fixture's signals, n samples, into a capture: with its truth and encoder, or as a
// real encoder's t,sin,cos alone.
void write_capture(const Scenario& gen, std::size_t n, const std::filesystem::path& path, bool with_truth) {
    test::write_generated_capture(gen.encoder, gen.motion, gen.sample_rate_hz, gen.seed, n, path, with_truth);
}
}  // namespace

TEST_CASE("self-reference: a capture without truth is measured, and agrees with the same capture with truth", "[selfref][capture]") {
    TempDir d;
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    const auto with = d.path / "with.fcap", without = d.path / "without.fcap";
    write_capture(gen, 200000, with, true);
    write_capture(gen, 200000, without, false);
    CaptureRunOptions o;
    o.estimator = "atan2";
    o.capture_path = without.string();
    const json bare = run_capture(o);
    o.capture_path = with.string();
    o.encoder = gen.encoder;
    const json scored = run_capture(o);
    REQUIRE(bare["status"] == "done");
    CHECK(bare["verdict"].is_null());
    CHECK(bare["scenario"]["scoring"]["self_reference"] == true);
    const json& sr = bare["estimators"][0]["analysers"]["self_reference"];
    REQUIRE(sr["measured"] == true);
    // With truth the run does not measure it unless asked; the truth-scored figure is the judge.
    CHECK_FALSE(scored["estimators"][0].contains("analysers"));
    const double truth = scored["estimators"][0]["metrics"]["std"]["rad"].get<double>();
    INFO("truth std " << truth << " self-referenced " << sr["rms_rad"]);
    CHECK(sr["rms_rad"].get<double>() == Approx(truth).epsilon(0.1));
}

TEST_CASE("self-reference: a run on a capture without truth is judged on the self-referenced figures, not FAILed for lack of truth", "[selfref][capture][run]") {
    TempDir d;
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    const auto cap = d.path / "bare.fcap";
    write_capture(gen, 150000, cap, false);
    auto scenario = [&](json limits) {
        json j{{"name", "bare-capture"}, {"encoder", gen.encoder}, {"motion", {{"kind", "constant"}, {"electrical_freq_hz", 100.0}}},
               {"sample_rate_hz", gen.sample_rate_hz}, {"duration_s", 150000 / gen.sample_rate_hz}, {"settle_s", 0.05}, {"seed", 1},
               {"device", "capture:" + cap.string()}, {"estimators", json::array({json{{"name", "atan2"}}})}, {"limits", std::move(limits)}};
        return scenario_from_json(j, FRINGE_SOURCE_DIR "/fixtures/scenarios");
    };
    SECTION("a limit on the self-referenced rms: PASS on the evidence of the self-referenced windows") {
        const json r = execute_run(scenario(json::array({json{{"estimator", "atan2"}, {"metric", "self_ref_rms_rad"}, {"max", 0.5}}})));
        REQUIRE(r["status"] == "done");
        CHECK(r["verdict"] == "PASS");
        std::set<std::string> metrics;
        for (const auto& m : r["measurements"]) {
            metrics.insert(m["metric"].get<std::string>());
            CHECK(m["outcome"] == "PASS");
        }
        CHECK(metrics == std::set<std::string>{"self_ref_samples", "self_ref_cycles", "self_ref_valid_fraction", "self_ref_rms_rad"});
        CHECK(r["estimators"][0]["analysers"]["self_reference"]["measured"] == true);
        CHECK(r["estimators"][0]["diagnosis"].empty());  // atan2 vouched for its samples: not never_valid for want of truth
        for (const auto& w : r["warnings"]) CHECK(w["code"] != "never_valid");
        // The HTML says why there is no error spectrum: no truth, not a lack of scored samples.
        const std::string html = report_html(r);
        CHECK_THAT(html, Catch::Contains("this capture has no truth"));
        CHECK_THAT(html, Catch::Contains("self_ref_rms_rad"));
        CHECK_THAT(html, Catch::Contains("<svg id=\"plot-self-reference\""));  // the sub-divisional error from its harmonics
    }
    SECTION("a limit the capture cannot measure (rms_rad needs truth) FAILs and says why") {
        const json r = execute_run(scenario(json::array({json{{"estimator", "atan2"}, {"metric", "rms_rad"}, {"max", 0.5}}})));
        REQUIRE(r["status"] == "done");
        CHECK(r["verdict"] == "FAIL");
        bool seen = false;
        for (const auto& m : r["measurements"])
            if (m["metric"] == "rms_rad") {
                seen = true;
                CHECK(m["outcome"] == "FAIL");
                CHECK_THAT(m["reason"].get<std::string>(), Catch::Contains("no truth") && Catch::Contains("self_ref_"));
            }
        CHECK(seen);
    }
    SECTION("a self-referenced limit it fails") {
        const json r = execute_run(scenario(json::array({json{{"estimator", "atan2"}, {"metric", "self_ref_rms_rad"}, {"max", 1e-9}}})));
        CHECK(r["verdict"] == "FAIL");
    }
}

TEST_CASE("capture without truth: the preflight's stand-in motion is the signals' own speed, not zero", "[selfref][capture][preflight]") {
    TempDir d;
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    const auto cap = d.path / "bare.fcap";
    write_capture(gen, 60000, cap, false);
    CaptureRunOptions o;
    o.capture_path = cap.string();
    o.estimator = "atan2";
    o.encoder = gen.encoder;
    const CapturePlan p = plan_capture_run(o);
    CHECK_FALSE(p.has_truth);
    // The generator's mean electrical speed over the settle time, from its own motion.
    const double settle = std::min(o.settle_s, 60000 / gen.sample_rate_hz);
    std::vector<double> t{0.0, settle}, phi(2), om(2), al(2);
    gen.motion.evaluate(t.data(), 2, phi.data(), om.data(), al.data());
    const double expect_rad_s = std::fabs(phi[1] - phi[0]) / settle;  // mechanical
    CHECK(p.run.scenario.motion.velocity_rad_s == Approx(expect_rad_s).epsilon(0.02));
}

TEST_CASE("a capture: run's preflight takes the motion from the capture, not from the scenario's motion", "[selfref][capture][preflight]") {
    // The scenario says 10x the capture's speed (a form started from another fixture): the
    // preflight's samples per cycle and ekf-auto's settle travel are the capture's.
    TempDir d;
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    for (const bool truth : {true, false}) {
        INFO((truth ? "with truth" : "without truth"));
        const auto cap = d.path / (truth ? "with.fcap" : "bare.fcap");
        write_capture(gen, 60000, cap, truth);
        std::vector<double> t{0.0, 0.1}, phi(2), om(2), al(2);
        gen.motion.evaluate(t.data(), 2, phi.data(), om.data(), al.data());
        const double capture_el_hz = std::fabs(phi[1] - phi[0]) / 0.1 * gen.encoder.lines_per_rev / kTwoPi;
        json j{{"name", "capture-motion"}, {"encoder", gen.encoder}, {"motion", {{"kind", "constant"}, {"electrical_freq_hz", 10 * capture_el_hz}}},
               {"sample_rate_hz", gen.sample_rate_hz}, {"duration_s", 60000 / gen.sample_rate_hz}, {"settle_s", 0.1}, {"seed", 1},
               {"device", "capture:" + cap.string()}, {"estimators", json::array({json{{"name", "ekf-auto"}}})}};
        const RunPlan p = plan_run(scenario_from_json(j, FRINGE_SOURCE_DIR "/fixtures/scenarios"));
        CHECK(p.scenario.motion_from_capture);
        CHECK(p.samples_per_cycle == Approx(gen.sample_rate_hz / capture_el_hz).epsilon(0.02));
        // ekf-auto's settle travel: the capture's cycles in 0.1 s (below its ~50), not ten times as many.
        bool learning = false;
        for (const auto& w : p.warnings)
            if (w.code == "scores_learning") {
                learning = true;
                // counted past the scan's 0.5 rad deadband: within 0.1 cycle of the travel
                const auto at = w.message.find("covers ");
                REQUIRE(at != std::string::npos);
                CHECK(std::stod(w.message.substr(at + 7)) == Approx(0.1 * capture_el_hz).margin(0.11));
            }
        CHECK(learning == (0.1 * capture_el_hz < 50));
        // A capture: scenario may leave its motion out or half filled in (a form's): it is not read.
        for (const json& m : {json(nullptr), json{{"kind", "constant"}}}) {
            json k = j;
            if (m.is_null()) k.erase("motion");
            else k["motion"] = m;
            const RunPlan pk = plan_run(scenario_from_json(k, FRINGE_SOURCE_DIR "/fixtures/scenarios"));
            CHECK(pk.samples_per_cycle == Approx(p.samples_per_cycle));
        }
        {  // another device still needs one
            json k = j;
            k.erase("motion");
            k["device"] = "loopback:";
            CHECK_THROWS_WITH(scenario_from_json(k, FRINGE_SOURCE_DIR "/fixtures/scenarios"), Catch::Contains("motion"));
        }
        // A capture that cannot be read leaves the scenario's motion: the run's device names the fault.
        j["device"] = "capture:" + (d.path / "missing.fcap").string();
        const RunPlan q = plan_run(scenario_from_json(j, FRINGE_SOURCE_DIR "/fixtures/scenarios"));
        CHECK_FALSE(q.scenario.motion_from_capture);
    }
}

TEST_CASE("self-reference: the preflight says when a capture's motion cannot give it", "[selfref][capture][preflight]") {
    // The rule on the capture's own figures (docs/self-reference.md "What it cannot see").
    const SelfReferenceOptions so;
    CaptureScan s;
    s.sample_rate_hz = 100000;
    s.samples = 100000;  // 1 s
    auto cycles = [](double c) { return c * kTwoPi; };
    s.travel_rad = cycles(200);
    s.settle_travel_rad = cycles(20);
    CHECK_FALSE(self_reference_motion_check(s, 0.1).has_value());  // 180 cycles at 500 samples a cycle
    s.travel_rad = cycles(2 * so.window_cycles + 20 - 0.5);         // just below two windows after the settle time
    auto f = self_reference_motion_check(s, 0.1);
    REQUIRE(f.has_value());
    CHECK(f->code == "self_reference_motion");
    CHECK_THAT(f->message, Catch::Contains("travels 31.5 electrical cycles after the settle time"));
    s.travel_rad = cycles(2 * so.window_cycles + 20 + 0.5);
    CHECK_FALSE(self_reference_motion_check(s, 0.1).has_value());
    // Slow: 40 cycles over 100 s at 100 kHz is 250 000 samples a cycle; a window holds 65 536.
    s.samples = 10000000;
    s.travel_rad = cycles(40);
    s.settle_travel_rad = 0;
    f = self_reference_motion_check(s, 0.0);
    REQUIRE(f.has_value());
    CHECK(f->field == "sample_rate_hz");
    CHECK_THAT(f->message, Catch::Contains("2.5e+05 samples per electrical cycle"));
    // No motion at all.
    s.travel_rad = 0;
    CHECK(self_reference_motion_check(s, 0.0).has_value());

    SECTION("end to end: a short capture without truth carries the warning, through fringe estimate's path and a capture: run") {
        TempDir d;
        const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
        const auto cap = d.path / "short.fcap";
        std::vector<double> t{0.0, 0.05}, phi(2), om(2), al(2);
        gen.motion.evaluate(t.data(), 2, phi.data(), om.data(), al.data());
        const double el_hz = std::fabs(phi[1] - phi[0]) / 0.05 * gen.encoder.lines_per_rev / kTwoPi;
        const std::size_t n = static_cast<std::size_t>(20.0 / el_hz * gen.sample_rate_hz);  // about 20 electrical cycles
        write_capture(gen, n, cap, false);
        CaptureRunOptions o;
        o.capture_path = cap.string();
        o.estimator = "atan2";
        o.settle_s = 0;
        const json r = run_capture(o);
        bool warned = false;
        for (const auto& w : r["warnings"]) warned |= w["code"] == "self_reference_motion";
        CHECK(warned);
        json j{{"name", "short"}, {"encoder", gen.encoder}, {"motion", {{"kind", "constant"}, {"electrical_freq_hz", 1000.0}}},
               {"sample_rate_hz", gen.sample_rate_hz}, {"duration_s", static_cast<double>(n) / gen.sample_rate_hz}, {"settle_s", 0.0}, {"seed", 1},
               {"device", "capture:" + cap.string()}, {"estimators", json::array({json{{"name", "atan2"}}})}};
        const RunPlan p = plan_run(scenario_from_json(j, FRINGE_SOURCE_DIR "/fixtures/scenarios"));
        warned = false;
        for (const auto& w : p.warnings) warned |= w.code == "self_reference_motion";
        CHECK(warned);
    }
}

TEST_CASE("capture scan: a standing encoder's noisy phase is no travel, a swing is its whole distance", "[selfref][capture][preflight]") {
    TempDir d;
    const double fs = 100000;
    auto write = [&](const std::string& name, auto theta) {
        const auto path = d.path / name;
        CaptureWriter w(path.string(), CaptureColumns{false, false, false}, json{{"sample_rate_hz", fs}});
        Block b;
        const std::size_t n = 100000;
        b.resize(n, false);
        std::mt19937_64 rng(3);
        std::normal_distribution<double> g(0.0, 0.01);  // 10 mV on 0.5 V: 0.02 rad of phase jitter a sample
        for (std::size_t i = 0; i < n; ++i) {
            const double t = static_cast<double>(i) / fs, th = theta(t);
            b.t_s[i] = t;
            b.sin_v[i] = 0.5 * std::sin(th) + g(rng);
            b.cos_v[i] = 0.5 * std::cos(th) + g(rng);
        }
        w.write(b);
        w.close();
        return scan_capture(path.string(), CaptureOptions{}, 0.1);
    };
    const CaptureScan still = write("still.fcap", [](double) { return 0.7; });
    CHECK(still.travel_rad < 1.0);  // the per-sample jitter summed would be about 100000 x 0.02 x 0.8 = 1600 rad
    // Swinging +-3 periods twice a second for 1 s: 4 swings of 12 pi each = 24 cycles of distance.
    const CaptureScan swing = write("swing.fcap", [](double t) { return 3 * kTwoPi * std::sin(kTwoPi * 2 * t); });
    CHECK(swing.travel_rad == Approx(4 * 2 * 3 * kTwoPi).epsilon(0.04));  // each of the 8 turns loses at most the 0.5 rad deadband
}

TEST_CASE("a capture: scenario takes what it leaves out (rate, length, encoder, motion) from the capture", "[selfref][capture][preflight]") {
    TempDir d;
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    for (const bool truth : {true, false}) {
        INFO((truth ? "with truth (and the encoder in its metadata)" : "without truth"));
        const auto cap = d.path / (truth ? "with.fcap" : "bare.fcap");
        write_capture(gen, 40000, cap, truth);
        const json j{{"name", "minimal"}, {"device", "capture:" + cap.string()}, {"estimators", json::array({json{{"name", "atan2"}}})}};
        const Scenario parsed = scenario_from_json(j, FRINGE_SOURCE_DIR "/fixtures/scenarios");
        CHECK(parsed.length_from_capture);
        const RunPlan p = plan_run(parsed);
        CHECK(p.scenario.sample_rate_hz == gen.sample_rate_hz);
        CHECK(p.scenario.samples() == 40000);
        CHECK(p.scenario.encoder_known == truth);  // the capture's own encoder, from its metadata
        if (truth) CHECK(p.scenario.encoder.lines_per_rev == gen.encoder.lines_per_rev);
        const json r = execute_run(plan_run(parsed));
        CHECK(r["status"] == "done");
        CHECK(r["samples"]["processed"] == 40000);
        CHECK(r["scenario"]["duration_s"].get<double>() == Approx(40000 / gen.sample_rate_hz));
    }
    // Left out and unreadable: the scenario's field is named with the capture's fault.
    const json missing{{"name", "minimal"}, {"device", "capture:" + (d.path / "none.fcap").string()}, {"estimators", json::array({json{{"name", "atan2"}}})}};
    CHECK_THROWS_WITH(plan_run(scenario_from_json(missing, FRINGE_SOURCE_DIR "/fixtures/scenarios")),
                      Catch::Contains("not given, and the capture could not be read"));
    // Another device still needs them.
    json loop = missing;
    loop["device"] = "loopback:";
    CHECK_THROWS(scenario_from_json(loop, FRINGE_SOURCE_DIR "/fixtures/scenarios"));
}

}  // namespace test_self_reference_cpp
