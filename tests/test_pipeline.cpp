// One pipeline: the same capture through `fringe estimate` (the built executable), the HTTP
// evaluation (Service::handle, after an upload) and a run of a scenario file whose device is
// capture:PATH gives identical figures, in the same report schema; so does a DUT's ABZ lane.
#include "helpers.hpp"
#include "drivers/capture_file.hpp"
#include "server/engine/capture_run.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/http/service.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/generator.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_pipeline_cpp {

using namespace fringe;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

using test::TempDir;

std::string read_all(const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(f), {});
}

void write_all(const fs::path& p, const std::string& s) {
    std::ofstream f(p, std::ios::binary);
    f << s;
}

HttpRequest req(const std::string& method, const std::string& target, const std::string& body) {
    HttpRequest r;
    r.method = method;
    r.target = target;
    r.body = body;
    r.headers["authorization"] = "Bearer 0123456789abcdef0123456789abcdef";
    return r;
}

}  // namespace

TEST_CASE("one pipeline: fringe estimate, HTTP evaluate and a capture: run give identical figures", "[pipeline][capture][run][service]") {
    TempDir d;
    // The paper's 1.6 % duty-cycle encoder with its noise, 0.3 s at 100 kHz, as a .fcap with its encoder.
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    const std::uint64_t n = 30000;
    const fs::path cap = d.path / "cap.fcap";
    {
        Generator g(gen.encoder, gen.motion, gen.sample_rate_hz, gen.seed);
        Block b;
        b.resize(n, false);
        g.generate(0, b);
        CaptureWriter w(cap.string(), CaptureColumns{true, true, false}, json{{"sample_rate_hz", gen.sample_rate_hz}, {"t0_s", 0.0}, {"encoder", gen.encoder}});
        w.write(b);
    }
    ServiceConfig cfg;
    cfg.data_dir = (d.path / "data").string();
    cfg.fixtures_dir = FRINGE_SOURCE_DIR "/fixtures";
    cfg.web_dir = FRINGE_SOURCE_DIR "/web";
    cfg.token = "0123456789abcdef0123456789abcdef";
    cfg.workers = 1;
    cfg.max_upload_bytes = 8 << 20;
    Service service(cfg);
    const auto up = service.handle(req("POST", "/api/v1/captures", read_all(cap)));
    REQUIRE(up.status == 201);
    const std::string id = json::parse(up.body)["id"];

    struct Case {
        std::string estimator;
        json params;
        std::string cli_params;
    };
    for (const Case& c : {Case{"ekf-diffraction", json::object(), ""}, Case{"pll2", json{{"natural_freq_hz", 50}}, " --param natural_freq_hz=50"}}) {
        INFO(c.estimator);
        // 1. fringe estimate, the built executable
        const fs::path est_report = d.path / ("estimate-" + c.estimator + ".json");
        const std::string cmd = std::string(FRINGE_CLI) + " estimate " + cap.string() + " --estimator " + c.estimator + c.cli_params +
                                " --settle-s 0.1 -q --report " + est_report.string() + " -o " + (d.path / "est.csv").string();
        REQUIRE(std::system(cmd.c_str()) == 0);
        const json a = json::parse(read_all(est_report));
        // 2. POST /api/v1/captures/{id}/evaluate
        const auto ev = service.handle(req("POST", "/api/v1/captures/" + id + "/evaluate",
                                           json{{"estimator", c.estimator}, {"params", c.params}, {"settle_s", 0.1}}.dump()));
        REQUIRE(ev.status == 200);
        const json b = json::parse(ev.body);
        // 3. a scenario file with device capture:PATH, run by the engine
        const json scj{{"name", "capture run"}, {"encoder", gen.encoder}, {"motion", {{"kind", "constant"}, {"velocity_rad_s", 0.6}}},
                       {"sample_rate_hz", gen.sample_rate_hz}, {"duration_s", static_cast<double>(n) / gen.sample_rate_hz},
                       {"device", "capture:" + cap.string()}, {"settle_s", 0.1},
                       {"estimators", json::array({{{"name", c.estimator}, {"params", c.params}}})}};
        write_all(d.path / "run.json", scj.dump());
        const json r = execute_run(load_scenario((d.path / "run.json").string()));

        for (const json* x : {&a, &b, &r}) {
            CHECK((*x)["schema"] == "fringe.report");
            CHECK((*x)["schema_version"] == 3);
            CHECK((*x)["status"] == "done");
            CHECK((*x)["samples"]["processed"] == n);
        }
        CHECK(a["capture"]["encoder_source"] == "capture metadata");
        CHECK(b["capture"]["id"] == id);
        CHECK_FALSE(b.contains("traces"));  // the HTTP answer leaves out the plot data
        CHECK(a["traces"].is_object());
        const json& ma = a["estimators"][0]["metrics"];
        const json& mb = b["estimators"][0]["metrics"];
        const json& mr = r["estimators"][0]["metrics"];
        REQUIRE(ma["scored"] == 20000);
        CHECK(ma["rms"]["rad"].get<double>() > 0);
        for (const char* k : {"rms", "std", "mean", "max_abs"}) {
            INFO(k);
            CHECK(ma[k]["rad"].get<double>() == mb[k]["rad"].get<double>());
            CHECK(ma[k]["rad"].get<double>() == mr[k]["rad"].get<double>());
        }
        CHECK(ma["scored"] == mb["scored"]);
        CHECK(ma["scored"] == mr["scored"]);
        CHECK(ma["harmonics"].size() == 16);
        CHECK(ma["harmonics"] == mb["harmonics"]);
        CHECK(ma["harmonics"] == mr["harmonics"]);
        // and everything else scored (uncertainty, evidence, lock), the bounds, the verdict
        CHECK(ma == mb);
        CHECK(ma == mr);
        CHECK(a["estimators"][0]["bounds"] == b["estimators"][0]["bounds"]);
        CHECK(a["estimators"][0]["bounds"] == r["estimators"][0]["bounds"]);
        CHECK(a["verdict"] == r["verdict"]);
        CHECK(a["measurements"] == r["measurements"]);
    }
}

TEST_CASE("one pipeline: a capture without truth gives estimates and no verdict", "[pipeline][capture]") {
    TempDir d;
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    const fs::path cap = d.path / "notruth.fcap";
    {
        Generator g(gen.encoder, gen.motion, gen.sample_rate_hz, gen.seed);
        Block b;
        b.resize(5000, false);
        g.generate(0, b);
        CaptureWriter w(cap.string(), CaptureColumns{false, false, false}, json{{"sample_rate_hz", gen.sample_rate_hz}});
        w.write(b);
    }
    CaptureRunOptions o;
    o.capture_path = cap.string();
    o.estimator = "atan2";
    o.estimates_path = (d.path / "e.csv").string();
    const json r = run_capture(o);
    CHECK(r["status"] == "done");
    CHECK(r["verdict"].is_null());  // never scored: no PASS, and no FAIL either
    CHECK(r["measurements"].empty());
    CHECK(r["capture"]["has_truth"] == false);
    CHECK(r["capture"]["not_scored"].get<std::string>().find("no theta_true") != std::string::npos);
    CHECK(r["capture"]["estimates"]["samples"] == 5000);
    CHECK(r["capture"]["estimates"]["valid_fraction"] == 1.0);
    CHECK(r["capture"]["encoder_source"] == "none");
    CHECK(r["capture"]["no_encoder"].is_string());
    CHECK(r["scenario"]["encoder"].is_null());
    CHECK(r["estimators"][0]["metrics"]["scored"] == 0);
    CHECK(r["estimators"][0]["bounds"].is_null());
    CHECK(exit_code(r) == 2);  // no verdict is no success for a gate that reads the verdict
    std::ifstream f(o.estimates_path);
    std::string line;
    int rows = 0;
    while (std::getline(f, line)) ++rows;
    CHECK(rows == 5001);
}

TEST_CASE("one pipeline: a DUT's ABZ lines score the same through fringe estimate and a capture: run", "[pipeline][capture][run]") {
    TempDir d;
    const Scenario gen = load_scenario(FRINGE_SOURCE_DIR "/fixtures/scenarios/paper-duty1p6.json");
    const std::uint64_t n = 30000;
    const int N = 16;  // an ideal interpolator: A/B Gray code of floor(theta / step), Z at count 0 mod 4N
    const fs::path cap = d.path / "abz.csv";
    {
        Generator g(gen.encoder, gen.motion, gen.sample_rate_hz, gen.seed);
        Block b;
        b.resize(n, false);
        g.generate(0, b);
        std::ofstream f(cap);
        f << "t,sin,cos,theta_true,a,b,z\n";
        const double step = kTwoPi / (4 * N);
        const int gray_a[4] = {0, 1, 1, 0}, gray_b[4] = {0, 0, 1, 1};
        char line[256];
        for (std::size_t i = 0; i < n; ++i) {
            const long long k = static_cast<long long>(std::floor(b.theta_rad[i] / step));
            const int q = static_cast<int>(((k % 4) + 4) % 4);
            std::snprintf(line, sizeof line, "%.17g,%.17g,%.17g,%.17g,%d,%d,%d\n", b.t_s[i], b.sin_v[i], b.cos_v[i], b.theta_rad[i], gray_a[q], gray_b[q],
                          ((k % (4 * N)) + 4 * N) % (4 * N) == 0 ? 1 : 0);
            f << line;
        }
        write_all(d.path / "abz.json", json{{"sample_rate_hz", gen.sample_rate_hz}, {"t0_s", 0.0}, {"encoder", gen.encoder}}.dump());
    }
    const fs::path est_report = d.path / "estimate.json";
    const std::string cmd = std::string(FRINGE_CLI) + " estimate " + cap.string() + " --estimator atan2 --dut-interpolation " + std::to_string(N) +
                            " -q --report " + est_report.string();
    REQUIRE(std::system(cmd.c_str()) == 0);
    const json a = json::parse(read_all(est_report));
    const json scj{{"name", "abz run"}, {"encoder", gen.encoder}, {"motion", {{"kind", "constant"}, {"velocity_rad_s", 0.6}}},
                   {"sample_rate_hz", gen.sample_rate_hz}, {"duration_s", static_cast<double>(n) / gen.sample_rate_hz},
                   {"device", "capture:" + cap.string() + "?interpolation=" + std::to_string(N)}, {"settle_s", 0.1},
                   {"estimators", json::array({{{"name", "atan2"}}})}};
    write_all(d.path / "run.json", scj.dump());
    const json r = execute_run(load_scenario((d.path / "run.json").string()));
    REQUIRE(a["estimators"].size() == 2);
    REQUIRE(r["estimators"].size() == 2);
    CHECK(a["estimators"][1]["label"] == "dut");
    CHECK(r["estimators"][1]["label"] == "dut");
    const json& da = a["estimators"][1]["metrics"];
    CHECK(da["scored"] == 20000);
    CHECK(da["abz"]["illegal_transitions"] == 0);
    CHECK(da["max_abs"]["rad"].get<double>() <= kTwoPi / (4 * N) / 2 + 1e-9);  // an ideal DUT's quantisation
    CHECK(da == r["estimators"][1]["metrics"]);
    CHECK(a["estimators"][0]["metrics"] == r["estimators"][0]["metrics"]);
    CHECK(a["measurements"] == r["measurements"]);
}

}  // namespace test_pipeline_cpp
