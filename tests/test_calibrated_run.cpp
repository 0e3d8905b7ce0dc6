// "Calibrate, apply, re-run" in one run (a scenario's "calibrate"; server/engine/calibrated_run.hpp,
// docs/calibration.md "In one run"): the before and after passes in one report against the
// per-sample CRB, on the paper's signal, a Lissajous-distorted one and a capture without truth;
// what is refused when the scenario is checked; and the report when there is no after pass.
#include "board_sim_thread.hpp"
#include "helpers.hpp"

#include "server/engine/plan.hpp"
#include "server/engine/provenance.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <sstream>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_calibrated_run_cpp {

using namespace fringe;
using nlohmann::json;
using test::TempDir;
namespace fs = std::filesystem;

namespace {

json paper_with(json calibrate, json estimators = json::array({json{{"name", "atan2"}}})) {
    json j = load_json_file(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    j["estimators"] = std::move(estimators);
    j["calibrate"] = std::move(calibrate);
    return j;
}

Scenario scenario(const json& j) { return scenario_from_json(j, FRINGE_SOURCE_DIR "/fixtures/scenarios"); }

json run(const json& j, const TempDir& d, const std::atomic<bool>* cancel = nullptr, std::function<void(std::uint64_t, std::uint64_t)> progress = {}) {
    RunOptions o;
    o.calibration_dir = d.path.string();
    o.cancel = cancel;
    o.progress = std::move(progress);
    o.threads = 2;
    return execute_run(plan_run(scenario(j)), o);
}

const json& lane(const json& r, const std::string& label) {
    for (const auto& l : r["calibration"]["lanes"])
        if (l["label"] == label) return l;
    FAIL("no lane " << label);
    static const json none;
    return none;
}

std::string read(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    std::ostringstream s;
    s << f.rdbuf();
    return s.str();
}

}  // namespace

TEST_CASE("calibrated run: the paper's 1.6 % duty-cycle signal, before and after in one report, after within 2x of the per-sample CRB", "[calibration][calrun]") {
    TempDir d;
    const json j = paper_with({{"lane", "atan2"}}, json::array({json{{"name", "atan2"}}, json{{"name", "pll2"}}, json{{"name", "ekf-ideal"}, {"label", "ekf"}}}));
    const json r = run(j, d);
    REQUIRE(r["status"] == "done");
    const json& c = r["calibration"];
    REQUIRE(c["status"] == "verified");
    // which capture computed it and which verified it
    CHECK(c["computed_on"]["pass"] == "before");
    CHECK(c["computed_on"]["seed"] == 1);
    CHECK(c["computed_on"]["error_source"] == "truth");
    CHECK(c["verified_on"]["pass"] == "after");
    CHECK(c["verified_on"]["seed"] == 2);
    CHECK(r["seed"] == 2);  // the report's own figures are the after pass's
    // the correction: a file in the folder asked for, its hash, and the whole of it in the record
    const std::string path = c["correction"]["path"].get<std::string>();
    CHECK(std::filesystem::path(path).parent_path() == d.path);
    CHECK(sha256_hex(read(path)) == c["correction"]["sha256"]);
    CHECK(json::parse(read(path)) == c["correction"]["file"]);
    CHECK(c["correction"]["file"]["table_rad"].size() == 64);
    // the before pass is kept whole
    CHECK(c["before"]["status"] == "done");
    CHECK(c["before"]["seed"] == 1);
    REQUIRE(c["before"]["estimators"].size() == 3);
    CHECK_FALSE(c["before"]["estimators"][0].contains("spectrum"));  // the plot data is the after pass's
    const json& a = lane(r, "atan2");
    const double before = a["before"]["rms_rad"].get<double>(), after = a["after"]["rms_rad"].get<double>();
    const double crb = a["after"]["per_sample_crb_rad"].get<double>(), predicted = a["predicted_rms_rad"].get<double>();
    INFO("atan2 rms before " << before << " after " << after << " predicted " << predicted << " CRB " << crb);
    CHECK(before == Approx(1.78e-2).epsilon(0.02));
    CHECK(before == c["before"]["estimators"][0]["metrics"]["rms"]["rad"].get<double>());
    CHECK(after == r["estimators"][0]["metrics"]["rms"]["rad"].get<double>());
    CHECK(after < 2 * crb);
    CHECK(after == Approx(predicted).epsilon(0.15));
    CHECK(a["after"]["max_abs_rad"].get<double>() < a["before"]["max_abs_rad"].get<double>() / 10);
    CHECK(a["before"]["harmonics"].size() == a["after"]["harmonics"].size());
    CHECK(a["correction"]["applied"] == true);
    CHECK(a["correction"]["kind"] == "estimator_param");
    // pll2 takes the same correction; an EKF cannot, and runs as before
    const json& p = lane(r, "pll2");
    CHECK(p["correction"]["applied"] == true);
    CHECK(p["after"]["rms_rad"].get<double>() < p["before"]["rms_rad"].get<double>() / 20);
    const json& e = lane(r, "ekf");
    CHECK(e["correction"]["applied"] == false);
    CHECK(e["correction"]["why_not"].get<std::string>().find("takes no correction") != std::string::npos);
    CHECK(r["scenario"]["estimators"][2]["params"].value("correction", json()).is_null());
    // the board kind is named, not silently skipped
    CHECK(c["limits"].get<std::string>().find("after pass") != std::string::npos);
}

TEST_CASE("calibrated run: offsets, gain mismatch and quadrature error, after within 1.2x of the per-sample CRB", "[calibration][calrun]") {
    TempDir d;
    json j = paper_with({{"lane", "atan2"}, {"verify", {{"seed", 7}}}});
    // atan2 is told an ideal encoder: the signals have 4 % / -3 % offsets, 5 % gain mismatch, 0.04 rad quadrature error
    json enc = load_json_file(FRINGE_SOURCE_DIR "/fixtures/encoders/ideal.json");
    j["estimators"][0]["encoder"] = enc;
    enc["lissajous"] = {{"offset_sin_v", 0.04}, {"offset_cos_v", -0.03}, {"gain_mismatch", 0.05}, {"quadrature_error_rad", 0.04}};
    j["encoder"] = enc;
    const json r = run(j, d);
    REQUIRE(r["status"] == "done");
    REQUIRE(r["calibration"]["status"] == "verified");
    CHECK(r["calibration"]["verified_on"]["seed"] == 7);
    const json& a = lane(r, "atan2");
    const double before = a["before"]["rms_rad"].get<double>(), after = a["after"]["rms_rad"].get<double>();
    const double crb = a["after"]["per_sample_crb_rad"].get<double>();
    INFO("atan2 rms before " << before << " after " << after << " predicted " << a["predicted_rms_rad"] << " CRB " << crb);
    CHECK(before > 10 * crb);
    CHECK(after < 1.2 * crb);
    const json& lis = r["calibration"]["correction"]["file"]["lissajous"];
    CHECK(lis["offset_sin_v"].get<double>() == Approx(0.04).margin(1e-3));
    CHECK(lis["quadrature_error_rad"].get<double>() == Approx(0.04).margin(1e-3));
}

TEST_CASE("calibrated run: a capture without truth, calibrated self-referenced and verified on another capture, within 3x of the per-sample CRB", "[calibration][calrun][selfref]") {
    TempDir d;
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    const auto bare = d.path / "bare.fcap", b = d.path / "b.fcap";
    test::write_generated_capture(gen.encoder, gen.motion, gen.sample_rate_hz, 1, 200000, bare, false);
    test::write_generated_capture(gen.encoder, gen.motion, gen.sample_rate_hz, 2, 100000, b, true);
    const json j{{"name", "bare"},
                 {"device", "capture:" + bare.string()},
                 {"encoder", "../encoders/paper-d2-duty1p6.json"},
                 {"estimators", json::array({json{{"name", "atan2"}}})},
                 {"calibrate", {{"lane", "atan2"}, {"lissajous", GENERATE(true, false)}, {"verify", {{"device", "capture:" + b.string()}}}}}};
    const json r = run(j, d);
    REQUIRE(r["status"] == "done");
    const json& c = r["calibration"];
    REQUIRE(c["status"] == "verified");
    CHECK(c["correction"]["file"].contains("lissajous") == j["calibrate"]["lissajous"].get<bool>());
    CHECK(c["computed_on"]["error_source"] == "self_reference");
    CHECK(c["computed_on"]["capture"] == bare.string());
    CHECK(c["verified_on"]["capture"] == b.string());
    CHECK(c["computed_on"]["seed"].is_null());  // the captures say nothing of a seed: not the scenario's
    CHECK(c["verified_on"]["seed"].is_null());
    const json& a = lane(r, "atan2");
    CHECK(a["before"]["error_source"] == "self_reference");
    CHECK(a["after"]["error_source"] == "truth");
    const double after = a["after"]["rms_rad"].get<double>(), crb = a["after"]["per_sample_crb_rad"].get<double>();
    INFO("Lissajous stage " << j["calibrate"]["lissajous"] << ": self-referenced before " << a["before"]["rms_rad"] << ", after (truth) " << after << " CRB " << crb);
    CHECK(after < 3 * crb);
    CHECK(r["samples"]["planned"] == 100000);  // the after pass took its own capture's length
}

TEST_CASE("calibrated run: the scenario's calibrate block is checked with the rest", "[calibration][calrun]") {
    auto refused = [](const json& j, const std::string& field, const std::string& words) {
        INFO(j["calibrate"].dump());
        try {
            (void)plan_run(scenario(j));
            FAIL("accepted");
        } catch (const ConfigError& e) {
            CHECK(e.field() == field);
            CHECK_THAT(e.message(), Catch::Contains(words));
        }
    };
    const json two = json::array({json{{"name", "atan2"}}, json{{"name", "ekf-ideal"}, {"label", "ekf"}}, json{{"name", "pll2"}}});
    refused(paper_with({{"lane", "atan3"}}, two), "calibrate.lane", "no estimator labelled 'atan3' in this scenario (its lanes: 'atan2', 'ekf', 'pll2')");
    refused(paper_with({{"lane", "ekf"}}, two), "calibrate.lane", "'ekf' runs ekf-ideal: a correction can only be computed for atan2's reading");
    refused(paper_with({{"lane", "atan2"}, {"table_size", 4097}}), "calibrate.table_size", "4096");
    CHECK_NOTHROW(plan_run(scenario(paper_with({{"lane", "atan2"}, {"table_size", 4096}}))));
    refused(paper_with({{"lane", "atan2"}, {"error_source", "reference"}}), "calibrate.error_source", "self_reference");
    refused(paper_with({{"lane", "atan2"}}, json::array({json{{"name", "atan2"}, {"params", {{"correction", "x.json"}}}}})), "calibrate.lane",
            "already applies a correction");
    refused(paper_with({{"lane", "atan2"}, {"verify", {{"seed", 1}}}}), "calibrate.verify.seed", "same capture as the before pass");
    refused(paper_with({{"lane", "atan2"}, {"verify", {{"device", "nope:"}}}}), "calibrate.verify.device", "");
    json cap = paper_with({{"lane", "atan2"}});
    cap["device"] = "capture:/nonexistent/a.fcap";
    refused(cap, "calibrate.verify.device", "name another capture");
    cap["calibrate"]["verify"] = {{"device", "capture:/nonexistent/a.fcap"}};
    refused(cap, "calibrate.verify.device", "the same capture");
    // The same capture or noise written another way (found by a hostile trial): the scenario's
    // motion copied into the verify block, the device in another spelling, the capture by another
    // path, a link or a copy.
    json same_motion = paper_with({{"lane", "atan2"}});
    same_motion["calibrate"]["verify"] = {{"seed", 1}, {"motion", scenario(same_motion).motion}};
    refused(same_motion, "calibrate.verify.seed", "same capture as the before pass");
    json same_device = paper_with({{"lane", "atan2"}});
    same_device["device"] = "loopback:";
    same_device["calibrate"]["verify"] = {{"seed", 1}, {"device", "loopback:?"}};
    refused(same_device, "calibrate.verify.seed", "same capture as the before pass");
    {
        TempDir d;
        const Scenario gen = scenario(paper_with({{"lane", "atan2"}}));
        fs::create_directories(d.path / "sub");
        test::write_generated_capture(gen.encoder, gen.motion, gen.sample_rate_hz, 1, 20000, d.path / "a.fcap", true);
        fs::create_symlink(d.path / "a.fcap", d.path / "link.fcap");
        fs::copy_file(d.path / "a.fcap", d.path / "copy.fcap");
        test::write_generated_capture(gen.encoder, gen.motion, gen.sample_rate_hz, 2, 20000, d.path / "b.fcap", true);
        json c2 = paper_with({{"lane", "atan2"}});
        c2["device"] = "capture:" + (d.path / "a.fcap").string();
        for (const std::string& other : std::vector<std::string>{(d.path / "sub" / ".." / "a.fcap").string(), (d.path / "link.fcap").string(), (d.path / "copy.fcap").string()}) {
            c2["calibrate"]["verify"] = {{"device", "capture:" + other}};
            refused(c2, "calibrate.verify.device", "the same capture");
        }
        c2["calibrate"]["verify"] = {{"device", "capture:" + (d.path / "b.fcap").string()}};
        CHECK_NOTHROW(plan_run(scenario(c2)));
    }
    // a service's budget counts both passes
    RunBudget budget;
    budget.max_samples = 150000;
    json one = paper_with({{"lane", "atan2"}});
    CHECK_THROWS_WITH(plan_run(scenario(one), budget), Catch::Contains("2e+05 samples over its before and after passes"));
    one.erase("calibrate");
    CHECK_NOTHROW(plan_run(scenario(one), budget));
    // keys and values, like every other key
    auto bad_key = [](const json& j, const std::string& field, const std::string& words) {
        try {
            (void)scenario(j);
            FAIL("accepted");
        } catch (const ConfigError& e) {
            CHECK_THAT(e.field(), Catch::StartsWith(field));
            CHECK_THAT(e.message(), Catch::Contains(words));
        }
    };
    bad_key(paper_with({{"lane", "atan2"}, {"tabel_size", 64}}), "calibrate.tabel_size", "did you mean 'table_size'");
    bad_key(paper_with({{"lane", "atan2"}, {"verify", {{"sead", 2}}}}), "calibrate.verify.sead", "did you mean 'seed'");
    bad_key(paper_with({{"lane", "atan2"}, {"table_size", 1}}), "calibrate.table_size", "");
    bad_key(paper_with({{"lane", "atan2"}, {"harmonics", 0}}), "calibrate.harmonics", "");
    bad_key(paper_with({{"table_size", 64}}), "calibrate.lane", "");
    bad_key(paper_with({{"lane", "atan2"}, {"verify", {{"motion", {{"kind", "constant"}}}}}}), "calibrate.verify.motion", "");
    // a scenario with the block written back reads the same
    const Scenario s = scenario(paper_with({{"lane", "atan2"}, {"table_size", 128}, {"verify", {{"seed", 9}, {"motion", {{"kind", "constant"}, {"velocity_rad_s", -1.0}}}}}}));
    const json back = json(s)["calibrate"];
    CHECK(back["table_size"] == 128);
    CHECK(back["verify"]["seed"] == 9);
    CHECK(json(scenario_from_json(json(s), ""))["calibrate"] == back);
}

TEST_CASE("calibrated run: an after pass that fails or is cancelled keeps the before pass and says the after pass did not complete", "[calibration][calrun]") {
    TempDir d;
    SECTION("the after pass's device loses samples") {
        const json r = run(paper_with({{"lane", "atan2"}, {"verify", {{"device", "loopback:?drop_after=50000&drop_count=10"}}}}), d);
        CHECK(r["status"] == "error");
        CHECK(r["verdict"] == "ERROR");
        CHECK_THAT(r["error"].get<std::string>(), Catch::StartsWith("the after pass did not complete: ") && Catch::Contains("lost"));
        const json& c = r["calibration"];
        CHECK(c["status"] == "after_incomplete");
        CHECK(c["before"]["status"] == "done");
        CHECK(c["before"]["verdict"] == "PASS");
        CHECK(lane(r, "atan2")["before"]["rms_rad"].get<double>() == Approx(1.78e-2).epsilon(0.02));
        CHECK(c["correction"].is_object());  // it was computed and applied
    }
    SECTION("cancelled during the after pass") {
        std::atomic<bool> cancel{false};
        const json r = run(paper_with({{"lane", "atan2"}}), d, &cancel, [&](std::uint64_t done, std::uint64_t total) {
            if (done > total / 2 + total / 8) cancel = true;
        });
        CHECK(r["status"] == "aborted");
        CHECK(r["calibration"]["status"] == "after_incomplete");
        CHECK_THAT(r["calibration"]["why"].get<std::string>(), Catch::Contains("cancelled"));
        CHECK(r["calibration"]["before"]["status"] == "done");
        CHECK(lane(r, "atan2")["before"]["rms_rad"].is_number());
    }
    SECTION("an after capture that cannot be read: refused before the before pass runs") {
        try {
            (void)plan_run(scenario(paper_with({{"lane", "atan2"}, {"verify", {{"device", "capture:/nonexistent/b.fcap"}}}})));
            FAIL("planned");
        } catch (const ConfigError& e) {
            CHECK(e.field() == "calibrate.verify.device");
            CHECK_THAT(e.message(), Catch::Contains("/nonexistent/b.fcap"));
        }
    }
}

TEST_CASE("calibrated run: too few cycles for a correction: none, the reason, and no verdict from the before pass", "[calibration][calrun]") {
    TempDir d;
    json j = paper_with({{"lane", "atan2"}});
    j["duration_s"] = 0.108;  // 0.85 of an electrical cycle after the settle time
    const json r = run(j, d);
    CHECK(r["status"] == "error");
    CHECK(r["verdict"] == "ERROR");
    const json& c = r["calibration"];
    CHECK(c["status"] == "no_correction");
    CHECK_THAT(c["why"].get<std::string>(), Catch::Contains("too few electrical cycles for a correction") && Catch::Contains("at least 1)"));
    CHECK_FALSE(c.contains("correction"));
    CHECK(c["after"].is_null());
    CHECK(c["before"]["status"] == "done");
    CHECK_THAT(c["limits"].get<std::string>(), Catch::Contains("no after pass") && Catch::Contains("the verdict is not theirs"));
    // nothing was left in the folder: no correction file, no capture
    CHECK(std::filesystem::is_empty(d.path));
    // A folder the run made for its correction (as the temporary one without --report) is
    // removed again when nothing came of it.
    RunOptions o;
    o.calibration_dir = (d.path / "made" / "here").string();
    o.threads = 2;
    const json r2 = execute_run(plan_run(scenario(j)), o);
    CHECK(r2["calibration"]["status"] == "no_correction");
    CHECK_FALSE(std::filesystem::exists(d.path / "made"));
    CHECK(std::filesystem::exists(d.path));
}

TEST_CASE("calibrated run: a pll2 lane calibrated (from atan2's reading of the signals) and both lanes corrected, the self-referenced error chosen with truth at hand", "[calibration][calrun]") {
    TempDir d;
    const json r = run(paper_with({{"lane", "pll"}, {"error_source", "self_reference"}},
                                  json::array({json{{"name", "atan2"}}, json{{"name", "pll2"}, {"label", "pll"}}})),
                       d);
    REQUIRE(r["status"] == "done");
    const json& c = r["calibration"];
    REQUIRE(c["status"] == "verified");
    CHECK(c["computed_on"]["error_source"] == "self_reference");
    CHECK(c["spec"]["error_source"] == "self_reference");
    const json& p = lane(r, "pll");
    CHECK(p["correction"]["applied"] == true);
    CHECK_FALSE(p.contains("predicted_rms_rad"));  // atan2's prediction does not describe a loop
    CHECK(p["before"]["error_source"] == "truth");
    const double before = p["before"]["rms_rad"].get<double>(), after = p["after"]["rms_rad"].get<double>();
    const double crb = p["after"]["per_sample_crb_rad"].get<double>();
    INFO("pll2 rms before " << before << " after " << after << " CRB " << crb << "; atan2 after " << lane(r, "atan2")["after"]["rms_rad"]);
    CHECK(p["change"] == "better");
    CHECK(before > 20 * after);
    CHECK(after < 3 * crb);
    CHECK(lane(r, "atan2")["change"] == "better");
}

TEST_CASE("calibrated run: verified at another speed in the other direction, with the seed the before pass had", "[calibration][calrun]") {
    TempDir d;
    const json r = run(paper_with({{"lane", "atan2"}, {"verify", {{"seed", 1}, {"motion", {{"kind", "constant"}, {"electrical_freq_hz", -80.0}}}}}}), d);
    REQUIRE(r["status"] == "done");
    const json& c = r["calibration"];
    REQUIRE(c["status"] == "verified");
    CHECK(c["computed_on"]["seed"] == 1);
    CHECK(c["verified_on"]["seed"] == 1);
    CHECK(c["computed_on"]["motion"] != c["verified_on"]["motion"]);
    CHECK(c["verified_on"]["motion"] == r["scenario"]["motion"]);
    const json& a = lane(r, "atan2");
    const double after = a["after"]["rms_rad"].get<double>(), crb = a["after"]["per_sample_crb_rad"].get<double>();
    INFO("atan2 before " << a["before"]["rms_rad"] << " (+106.7 Hz), after " << after << " (-80 Hz), CRB " << crb);
    CHECK(a["before"]["rms_rad"].get<double>() > 50 * crb);
    CHECK(after < 2 * crb);
}

TEST_CASE("calibrated run: with --record the before pass's capture is the recording, kept and named as the capture the correction was computed on", "[calibration][calrun]") {
    TempDir d;
    RunOptions o;
    o.calibration_dir = (d.path / "corr").string();
    o.record_path = (d.path / "before.fcap").string();
    o.threads = 2;
    const json r = execute_run(plan_run(scenario(paper_with({{"lane", "atan2"}}))), o);
    REQUIRE(r["calibration"]["status"] == "verified");
    CHECK(r["calibration"]["computed_on"]["capture"] == o.record_path);
    CHECK(r["calibration"]["calibrated_from"]["capture"] == o.record_path);
    CHECK(std::filesystem::exists(o.record_path));  // the user's recording stays
    CHECK(std::filesystem::exists(r["calibration"]["correction"]["path"].get<std::string>()));  // the folder is made when missing
    CHECK(r["calibration"]["verified_on"].value("capture", json()).is_null());  // the after pass is not recorded over it

    // Replaying that recording (recorded with seed 1), verified on a capture without a recorded
    // scenario: each pass names the seed its capture was recorded with, not this scenario's 5.
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    const auto other = d.path / "other.fcap";
    test::write_generated_capture(gen.encoder, gen.motion, gen.sample_rate_hz, 9, 100000, other, true);
    json replay = paper_with({{"lane", "atan2"}, {"verify", {{"device", "capture:" + other.string()}}}});
    replay["device"] = "capture:" + o.record_path;
    replay["seed"] = 5;
    RunOptions o2;
    o2.calibration_dir = (d.path / "corr2").string();
    o2.threads = 2;
    const json r2 = execute_run(plan_run(scenario(replay)), o2);
    REQUIRE(r2["calibration"]["status"] == "verified");
    CHECK(r2["calibration"]["computed_on"]["seed"] == 1);
    CHECK(r2["calibration"]["computed_on"]["motion"] == r["scenario"]["motion"]);
    CHECK(r2["calibration"]["verified_on"]["seed"].is_null());
    CHECK(r2["calibration"]["verified_on"]["capture"] == other.string());
}

TEST_CASE("calibrated run: an external estimator's lane is given the correction only where it declares correction=FILE, and says which", "[calibration][calrun]") {
    TempDir d;
    json j = paper_with({{"lane", "atan2"}}, json::array({json{{"name", "atan2"}},
                                                          json{{"name", "external"}, {"label", "ext"}, {"params", {{"command", FRINGE_EXTERNAL_HELPER}, {"model", "memoryless"}}}}}));
    j["duration_s"] = 0.5;
    const json r = run(j, d);
    REQUIRE(r["calibration"]["status"] == "verified");
    const json& e = lane(r, "ext");
    CHECK(e["correction"]["kind"] == "external_env");
    const json after_params = r["scenario"]["estimators"][1]["params"];
    if (e["correction"]["applied"] == true) {
        CHECK(after_params["correction"] == r["calibration"]["correction"]["path"]);
    } else {
        CHECK_THAT(e["correction"]["why_not"].get<std::string>(), Catch::StartsWith("not yet"));
        CHECK_FALSE(after_params.contains("correction"));
        // it ran as before: its error is atan2's uncorrected one, on another capture
        CHECK(e["after"]["rms_rad"].get<double>() == Approx(e["before"]["rms_rad"].get<double>()).epsilon(0.05));
    }
    CHECK(lane(r, "atan2")["after"]["rms_rad"].get<double>() < lane(r, "atan2")["before"]["rms_rad"].get<double>() / 20);
}

TEST_CASE("calibrated run: on the emulated Modbus DUT, one fringe run writes the correction to its registers and its error drops as fringe's atan2 with it does", "[calibration][calrun][modbus][socket]") {
    TempDir d;
    dev::BoardSimOptions o;
    o.board = "dut-interpolator";
    o.offset_sin_v = 0.03;
    o.offset_cos_v = -0.02;
    o.gain_mismatch = 0.04;
    o.noise_v = 2e-4;
    o.seed = 3;
    test::SimThread sim(o);
    REQUIRE(sim.failure.empty());
    json j = load_json_file(FRINGE_SOURCE_DIR "/fixtures/scenarios/modbus-step-sweep.json");
    j["device"] = sim.uri("board=dut-interpolator");
    j["calibrate"] = {{"lane", "atan2"}};
    j.erase("limits");
    const json r = run(j, d);
    INFO(r.value("error", json()).dump() << " " << r["calibration"].value("why", json()).dump());
    REQUIRE(r["status"] == "done");
    const json& c = r["calibration"];
    REQUIRE(c["status"] == "verified");
    const json& dut = lane(r, "dut");
    CHECK(dut["correction"]["kind"] == "board_registers");
    CHECK(dut["correction"]["applied"] == true);
    CHECK_THAT(dut["correction"]["how"].get<std::string>(), Catch::Contains("read back and verified; correction_enable = 1"));
    const double before = dut["before"]["rms_rad"].get<double>(), after = dut["after"]["rms_rad"].get<double>();
    const double sw = lane(r, "atan2")["after"]["rms_rad"].get<double>();
    INFO("DUT rms before " << before << " after " << after << "; fringe's atan2 with the file on the same pass " << sw << ", predicted " << c["predicted_rms_rad"]);
    CHECK(before > 0.02);
    CHECK(before / after > 30);
    // The board applies the file as atan2 does, at its registers' quantisation (2*pi/65536 rad per LSB).
    CHECK(std::fabs(after - sw) < 0.25 * sw + 5e-5);
    CHECK(c["board_before"]["cleared"] == true);
    CHECK(c["board_before"]["correction_enable_was"] == 0);

    // Again on the same board, which now holds and applies the first run's correction: it is
    // switched off for the before pass (a trial's second run measured 3.1e-4 "before" and
    // warned that the correction made it worse).
    const json r2 = run(j, d);
    REQUIRE(r2["calibration"]["status"] == "verified");
    CHECK(r2["calibration"]["board_before"]["correction_enable_was"] == 1);
    const double before2 = lane(r2, "dut")["before"]["rms_rad"].get<double>();
    INFO("second run: DUT before " << before2);
    CHECK(before2 > 0.02);
    CHECK(lane(r2, "dut")["change"] == "better");
    for (const auto& w : r2["warnings"]) CHECK(w["code"] != "calibration_worse");
}

TEST_CASE("calibrated run: a Modbus DUT the correction cannot be written to runs uncorrected, and its lane says why", "[calibration][calrun][modbus][socket]") {
    TempDir d;
    dev::BoardSimOptions o;
    o.offset_sin_v = 0.03;
    o.gain_mismatch = 0.04;
    std::string board = "dut-interpolator";
    json cal{{"lane", "atan2"}};
    std::string why;
    SECTION("a board with a table but no Lissajous trims, and a correction with a Lissajous stage") {
        json b = load_json_file(FRINGE_SOURCE_DIR "/fixtures/boards/dut-interpolator.json");
        for (auto it = b["registers"].begin(); it != b["registers"].end();) it = it.key().rfind("trim", 0) == 0 ? b["registers"].erase(it) : std::next(it);
        board = (d.path / "table-only-dut.json").string();
        std::ofstream(board) << b.dump();
        why = "--no-lissajous";
    }
    SECTION("a board profile without correction registers") {
        json b = load_json_file(FRINGE_SOURCE_DIR "/fixtures/boards/dut-interpolator.json");
        for (auto it = b["registers"].begin(); it != b["registers"].end();)
            it = it.key().rfind("correction", 0) == 0 || it.key().rfind("trim", 0) == 0 ? b["registers"].erase(it) : std::next(it);
        board = (d.path / "bare-dut.json").string();
        std::ofstream(board) << b.dump();
        why = "declares no correction registers";
    }
    o.board = board;
    test::SimThread sim(o);
    REQUIRE(sim.failure.empty());
    json j = load_json_file(FRINGE_SOURCE_DIR "/fixtures/scenarios/modbus-step-sweep.json");
    j["device"] = sim.uri("board=" + board);
    j["calibrate"] = cal;
    j.erase("limits");
    const json r = run(j, d);
    REQUIRE(r["status"] == "done");
    REQUIRE(r["calibration"]["status"] == "verified");
    const json& dut = lane(r, "dut");
    CHECK(dut["correction"]["kind"] == "board_registers");
    CHECK(dut["correction"]["applied"] == false);
    CHECK_THAT(dut["correction"]["why_not"].get<std::string>(), Catch::Contains(why) && Catch::Contains("its own position ran as before"));
    INFO("DUT rms before " << dut["before"]["rms_rad"] << " after " << dut["after"]["rms_rad"]);
    CHECK(dut["after"]["rms_rad"].get<double>() > 0.5 * dut["before"]["rms_rad"].get<double>());
    // the software lane is corrected all the same
    CHECK(lane(r, "atan2")["after"]["rms_rad"].get<double>() < lane(r, "atan2")["before"]["rms_rad"].get<double>() / 10);
}

TEST_CASE("calibrated run: a board with a correction table takes the correction at its own entry count, and another count given is refused with the scenario", "[calibration][calrun][modbus]") {
    TempDir d;
    json b = load_json_file(FRINGE_SOURCE_DIR "/fixtures/boards/dut-interpolator.json");
    b["registers"]["correction_table_rad"]["count"] = 32;
    const std::string board = (d.path / "dut-32.json").string();
    std::ofstream(board) << b.dump();
    json j = load_json_file(FRINGE_SOURCE_DIR "/fixtures/scenarios/modbus-step-sweep.json");
    j["device"] = "modbus+tcp://127.0.0.1:1?board=" + board;  // nothing is opened when the scenario is checked
    j["calibrate"] = {{"lane", "atan2"}};
    const RunPlan p = plan_run(scenario(j));
    CHECK(p.scenario.calibrate->table_size == 32);
    CHECK(json(p.scenario)["calibrate"]["table_size"] == 32);
    // left out, it is not written back: a service that reads the scenario again takes the board's too
    CHECK_FALSE(json(scenario(j))["calibrate"].contains("table_size"));
    j["calibrate"]["table_size"] = 64;
    try {
        (void)plan_run(scenario(j));
        FAIL("accepted");
    } catch (const ConfigError& e) {
        CHECK(e.field() == "calibrate.table_size");
        CHECK_THAT(e.message(), Catch::Contains("64 entries, but the board the after pass runs on holds 32"));
    }
    // a software-only run keeps the default
    j["device"] = "loopback:";
    j["calibrate"].erase("table_size");
    const RunPlan q = plan_run(scenario(j));
    CHECK(q.scenario.calibrate->table_size == 64);
    CHECK(json(q.scenario)["calibrate"]["table_size"] == 64);  // the report's scenario says the size used
}

}  // namespace test_calibrated_run_cpp
