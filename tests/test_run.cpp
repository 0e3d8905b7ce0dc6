// Devices (loopback, capture) and the run engine: limits, verdicts, faults, reproducibility,
// report renderings and the run history.
#include "helpers.hpp"

#include "drivers/capture_file.hpp"
#include "drivers/device.hpp"
#include "server/store/forward.hpp"
#include "server/store/pg_store.hpp"
#include "server/engine/provenance.hpp"
#include "server/report/report_formats.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/store/store.hpp"
#include "server/engine/sweep.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/noise.hpp"

#include <catch2/catch.hpp>

#include <cstring>
#include <fstream>
#include <set>
#include <filesystem>
#include <limits>
#include <sstream>
#include <unistd.h>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_run_cpp {

using namespace fringe;
using nlohmann::json;

namespace {
std::string fixture(const std::string& name) { return std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/" + name; }

Scenario short_run(double duration_s = 0.3) {
    Scenario sc = load_scenario(fixture("fig10c-loopback.json"));
    sc.duration_s = duration_s;
    return sc;
}

std::vector<double> sine(std::size_t n, double f_hz, double fs, double amp, double phase = 0) {
    std::vector<double> v(n);
    for (std::size_t i = 0; i < n; ++i) v[i] = amp * std::sin(kTwoPi * f_hz * static_cast<double>(i) / fs + phase);
    return v;
}
}  // namespace

TEST_CASE("loopback: transparent when ideal, exact latency, quantised on the ADC grid", "[device][loopback]") {
    const double fs = 1e5;
    auto s = sine(1000, 1000, fs, 1.0), c = sine(1000, 1000, fs, 1.0, kPi / 2);
    {
        auto d = dev::open("loopback:?dac_bits=0&adc_bits=0&latency_samples=7");
        d->stream()->start(fs);
        d->stream()->write(s, c);
        std::vector<double> rs(1007), rc(1007);
        const auto r = d->stream()->read(rs, rc, 0);
        REQUIRE(r.status == dev::StreamStatus::Ok);
        REQUIRE(r.frames == 1007);
        for (int k = 0; k < 7; ++k) CHECK(rs[k] == 0.0);
        for (std::size_t k = 0; k < 1000; ++k) REQUIRE(rs[k + 7] == s[k]);
        CHECK(d->info().latency_samples == 7);
    }
    {
        auto d = dev::open("loopback:?dac_bits=0&adc_bits=10&range_v=1.25&noise_lsb=0");
        d->stream()->start(fs);
        d->stream()->write(s, c);
        std::vector<double> rs(1000), rc(1000);
        d->stream()->read(rs, rc, 0);
        const double q = 2.5 / 1024;
        for (std::size_t k = 0; k < 1000; ++k) {
            const double code = (rs[k] + 1.25) / q;
            REQUIRE(std::fabs(code - std::round(code)) < 1e-9);
            REQUIRE(std::fabs(rs[k] - s[k]) <= q / 2 + 1e-12);
        }
    }
}

TEST_CASE("loopback: the same frames whatever the write and read sizes", "[device][loopback]") {
    // The chain works a block at a time in passes; sample by sample it must give the same
    // numbers, with every setting that changes its path (filters, noise, ideal converters, a
    // slower DAC, latency, saturation).
    const double fs = 1e5;
    const std::size_t n = 10000;
    auto s = sine(n, 1234, fs, 1.1), c = sine(n, 1234, fs, 1.1, kPi / 2);
    s[5000] = std::numeric_limits<double>::infinity();  // a non-finite input reaches the filters
    for (const std::string uri : {"loopback:?dac_bits=16&adc_bits=16", "loopback:?dac_bits=0&adc_bits=0&noise_v=1e-3&latency_samples=3",
                                  "loopback:?dac_bits=0&adc_bits=0", "loopback:?dac_bits=12&adc_bits=14&recon_cutoff_hz=30000&aa_cutoff_hz=20000",
                                  "loopback:?dac_bits=16&adc_bits=12&aa_cutoff_hz=25000&aa_order=1&dac_rate_hz=40000&saturate_after=9000"}) {
        CAPTURE(uri);
        auto whole_dev = dev::open(uri), bits_dev = dev::open(uri);
        dev::StreamPort* whole = whole_dev->stream();
        dev::StreamPort* bits = bits_dev->stream();
        REQUIRE(whole);
        REQUIRE(bits);
        whole->start(fs);
        bits->start(fs);
        whole->write(s, c);
        for (std::size_t k = 0; k < n; k += 7) {
            const std::size_t m = std::min<std::size_t>(7, n - k);
            bits->write(std::span(s).subspan(k, m), std::span(c).subspan(k, m));
        }
        std::vector<double> ws(n), wc(n), bs(n), bc(n);
        REQUIRE(whole->read(ws, wc, 0).frames == n);
        for (std::size_t k = 0; k < n; k += 13) {
            const std::size_t m = std::min<std::size_t>(13, n - k);
            REQUIRE(bits->read(std::span(bs).subspan(k, m), std::span(bc).subspan(k, m), 0).frames == m);
        }
        for (std::size_t k = 0; k < n; ++k) {
            REQUIRE(std::memcmp(&ws[k], &bs[k], sizeof(double)) == 0);  // bit for bit (NaN and -0 too)
            REQUIRE(std::memcmp(&wc[k], &bc[k], sizeof(double)) == 0);
        }
    }
}

TEST_CASE("loopback: the streamed noise is white, of noise_v rms, and not the generator's numbers for the same seed", "[device][loopback]") {
    // Ideal converters and a zero input: the output is noise_v times the chain's normals. Their
    // rms, mean and correlations against the normal distribution's (2^17 samples a channel:
    // the rms's standard error 0.2 %, a correlation's 0.3 %).
    const std::size_t n = std::size_t{1} << 17;
    const double nv = 1e-3;
    auto d = dev::open("loopback:?dac_bits=0&adc_bits=0&noise_lsb=0&noise_v=0.001&seed=1");
    dev::StreamPort* p = d->stream();
    REQUIRE(p);
    p->start(1e5);
    const std::vector<double> zero(n, 0.0);
    p->write(zero, zero);
    std::vector<double> a(n), b(n);
    REQUIRE(p->read(a, b, 0).frames == n);
    // the generator's normals for seed 1 (signal_gen/generator.cpp: NoiseField(seed, 1, 3))
    NoiseField gen_noise(1, 1, 3);
    std::vector<double> g0(n), g1(n), g2(n);
    double* g[3] = {g0.data(), g1.data(), g2.data()};
    gen_noise.fill(0, n, g);
    auto dot = [&](const std::vector<double>& x, const std::vector<double>& y) {
        double s2 = 0;
        for (std::size_t i = 0; i < n; ++i) s2 += x[i] * y[i];
        return s2 / static_cast<double>(n);
    };
    for (auto* ch : {&a, &b}) {
        double mean = 0;
        for (double& v : *ch) { v /= nv; mean += v; }
        mean /= static_cast<double>(n);
        CHECK(std::fabs(mean) < 0.015);                     // 5 standard errors
        CHECK(std::fabs(std::sqrt(dot(*ch, *ch)) - 1.0) < 0.01);
        for (const auto* gv : {&g0, &g1, &g2}) CHECK(std::fabs(dot(*ch, *gv)) < 0.015);
    }
    CHECK(std::fabs(dot(a, b)) < 0.015);  // the two channels independent
    // neighbouring samples uncorrelated (white)
    double lag1 = 0;
    for (std::size_t i = 1; i < n; ++i) lag1 += a[i] * a[i - 1];
    CHECK(std::fabs(lag1 / static_cast<double>(n - 1)) < 0.015);
}

TEST_CASE("loopback: a slower DAC holds each code until its next update", "[device][loopback]") {
    auto d = dev::open("loopback:?dac_bits=0&adc_bits=0&dac_rate_hz=25000");
    d->stream()->start(1e5);
    auto s = sine(400, 1000, 1e5, 1.0), c = sine(400, 1000, 1e5, 1.0, kPi / 2);
    d->stream()->write(s, c);
    std::vector<double> rs(400), rc(400);
    REQUIRE(d->stream()->read(rs, rc, 0).frames == 400);
    for (std::size_t k = 0; k < 400; ++k) REQUIRE(rs[k] == s[4 * (k / 4)]);
    auto bad = dev::open("loopback:?dac_rate_hz=2e5");
    CHECK_THROWS_WITH(bad->stream()->start(1e5), Catch::Contains("dac_rate_hz"));
}

TEST_CASE("loopback: anti-alias filter phase and gain match the analog Butterworth response", "[device][loopback]") {
    const double fs = 1e5, fc = 5000, f = 1000;
    const int order = GENERATE(1, 2);
    auto d = dev::open("loopback:?dac_bits=0&adc_bits=0&aa_cutoff_hz=5000&aa_order=" + std::to_string(order));
    d->stream()->start(fs);
    const std::size_t n = 20000;
    auto s = sine(n, f, fs, 1.0), c = sine(n, f, fs, 1.0, kPi / 2);
    d->stream()->write(s, c);
    std::vector<double> rs(n), rc(n);
    d->stream()->read(rs, rc, 0);
    // Fit a*sin + b*cos over the settled second half.
    double ss = 0, sc = 0, cc = 0, ys = 0, yc = 0;
    for (std::size_t i = n / 2; i < n; ++i) {
        const double x = kTwoPi * f * static_cast<double>(i) / fs, sn = std::sin(x), cs = std::cos(x);
        ss += sn * sn; sc += sn * cs; cc += cs * cs; ys += rs[i] * sn; yc += rs[i] * cs;
    }
    const double det = ss * cc - sc * sc, a = (ys * cc - yc * sc) / det, b = (yc * ss - ys * sc) / det;
    const double gain = std::hypot(a, b), phase = std::atan2(b, a);
    // Analog prototype at the frequency the bilinear transform (prewarped at fc) maps f to.
    const double u = std::tan(kPi * f / fs) / std::tan(kPi * fc / fs);
    const double want_gain = order == 1 ? 1 / std::sqrt(1 + u * u) : 1 / std::sqrt(1 + u * u * u * u);
    const double want_phase = order == 1 ? -std::atan(u) : -std::atan2(std::sqrt(2.0) * u, 1 - u * u);
    CHECK(gain == Approx(want_gain).epsilon(1e-6));
    CHECK(phase == Approx(want_phase).epsilon(1e-6));
}

TEST_CASE("loopback: injected faults are reported with exact counts", "[device][loopback][faults]") {
    auto d = dev::open("loopback:?drop_after=1000&drop_count=37&stall_after=3000");
    d->stream()->start(1e5);
    std::vector<double> z(4000, 0.0), rs(4000), rc(4000);
    d->stream()->write(z, z);
    auto r = d->stream()->read(std::span(rs).first(1000), std::span(rc).first(1000), 0);
    CHECK(r.status == dev::StreamStatus::Ok);
    CHECK(r.frames == 1000);
    r = d->stream()->read(std::span(rs).first(500), std::span(rc).first(500), 0);
    CHECK(r.status == dev::StreamStatus::Overflow);
    CHECK(r.dropped == 37);
    CHECK(r.first_index == 1037);
    r = d->stream()->read(rs, rc, 0);  // up to the stall point (3000 delivered)
    CHECK(r.status == dev::StreamStatus::Ok);
    CHECK(r.frames == 2000);
    CHECK(r.first_index == 1037);
    r = d->stream()->read(rs, rc, 0);
    CHECK(r.status == dev::StreamStatus::Timeout);
    CHECK_THROWS_WITH(dev::open("loopback:?adc_bitz=3"), Catch::Contains("device.adc_bitz") && Catch::Contains("unknown"));
    CHECK_THROWS_WITH(dev::open("loopback:?adc_bits=99"), Catch::Contains("device.adc_bits"));
    CHECK_THROWS_WITH(dev::open("warp:"), Catch::Contains("unknown driver 'warp'"));
    CHECK_THROWS_WITH(dev::open("capture:/nonexistent.fcap"), Catch::Contains("nonexistent.fcap"));
}

TEST_CASE("run: PASS, MARGINAL and FAIL from limits, and exit codes", "[run]") {
    Scenario sc = short_run();
    sc.estimators = {{"ekf-diffraction", "ekf", json::object(), std::nullopt}};
    auto run_with = [&](Limit l) -> json {
        sc.limits = {l};
        return execute_run(sc);
    };
    Limit l;
    l.metric = "rms_rad";
    l.max = 1e-3;
    auto r = run_with(l);
    const double rms = r["estimators"][0]["metrics"]["rms"]["rad"].get<double>();
    CHECK(r["verdict"] == "PASS");
    CHECK(exit_code(r) == 0);
    l.max = rms * 1.05;
    l.marginal_fraction = 0.1;
    r = run_with(l);
    CHECK(r["verdict"] == "MARGINAL");
    CHECK(exit_code(r) == 0);
    // Below the value's 95 % interval: a confident FAIL (inside it, MARGINAL: [uncertainty] tests).
    const double lo = r["estimators"][0]["metrics"]["uncertainty"]["rms_rad"][0].get<double>();
    l.max = lo * 0.9;
    r = run_with(l);
    CHECK(r["verdict"] == "FAIL");
    CHECK(exit_code(r) == 1);
    // the limit's measurement follows the estimator's five implicit evidence checks
    REQUIRE(r["measurements"].size() == 6);
    CHECK(r["measurements"][5]["outcome"] == "FAIL");
    CHECK(r["measurements"][5]["value"].get<double>() == rms);  // same seed: bit for bit
    for (int k = 0; k < 5; ++k) CHECK(r["measurements"][k]["implicit"] == true);
    l = {};
    l.metric = "efficiency";
    l.min = 0.5;
    r = run_with(l);
    CHECK(r["verdict"] == "PASS");
}

TEST_CASE("run: re-running with the same seed reproduces the metrics bit for bit", "[run]") {
    Scenario sc = short_run();
    const json a = execute_run(sc), b = execute_run(sc);
    CHECK(a["estimators"] == b["estimators"]);
    sc.seed = 2;
    const json c = execute_run(sc);
    CHECK(a["estimators"][1]["metrics"] != c["estimators"][1]["metrics"]);
}

TEST_CASE("run: device latency is compensated, sample loss and stalls end the run as ERROR", "[run][faults]") {
    Scenario sc = short_run();
    sc.device = "loopback:?dac_bits=16&adc_bits=16&latency_samples=25";
    json r = execute_run(sc);
    CHECK(r["status"] == "done");
    CHECK(r["estimators"][1]["metrics"]["rms"]["rad"].get<double>() < 4e-5);  // no 25-sample phase offset
    sc.device = "loopback:?drop_after=12345&drop_count=500";
    r = execute_run(sc);
    CHECK(r["status"] == "error");
    CHECK(r["verdict"] == "ERROR");
    CHECK(exit_code(r) == 2);
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("sample loss: 500 input samples dropped before input sample 12845"));
    for (const auto& m : r["measurements"]) CHECK(m["outcome"] == "ERROR");
    sc.device = "loopback:?stall_after=20000";
    r = execute_run(sc);
    CHECK(r["verdict"] == "ERROR");
    CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("timeout"));
    CHECK(r["samples"]["processed"].get<int>() < 30000);
    sc.device = "loopback:?saturate_after=10000";  // a railed ADC: the run completes and fails on accuracy
    sc.limits = {{"*", "rms_rad", 1e-3, std::nullopt, 0.0}};
    r = execute_run(sc);
    CHECK(r["status"] == "done");
    CHECK(r["verdict"] == "FAIL");
}

TEST_CASE("report: one struct, its keys as docs/schema.md lists them for a finished, a failed and an unstarted run", "[run][report][docs]") {
    // The table between the report-keys markers: each row's first cell names one or more keys.
    std::ifstream in(std::string(FRINGE_SOURCE_DIR) + "/docs/schema.md");
    REQUIRE(in);
    std::set<std::string> documented;
    bool inside = false;
    for (std::string line; std::getline(in, line);) {
        if (line.find("<!-- report-keys:begin") != std::string::npos) inside = true;
        else if (line.find("<!-- report-keys:end") != std::string::npos) inside = false;
        else if (inside && line.rfind("| `", 0) == 0) {
            const std::string cell = line.substr(2, line.find(" |", 2) - 2);
            for (std::size_t p = cell.find('`'); p != std::string::npos; p = cell.find('`', cell.find('`', p + 1) + 1))
                documented.insert(cell.substr(p + 1, cell.find('`', p + 1) - p - 1));
        }
    }
    REQUIRE(documented.size() >= 20);
    const std::set<std::string> optional_keys{"provenance", "capture", "calibration"};
    auto keys_of = [](const json& r) {
        std::set<std::string> k;
        for (const auto& [key, v] : r.items()) k.insert(key);
        return k;
    };
    Scenario sc = short_run(0.2);
    RunOptions o;
    o.provenance = json{{"dut", {{"serial", "SN-1"}}}};
    const json done = execute_run(sc, o);
    sc.device = "loopback:?drop_after=1000&drop_count=10";
    const json failed = execute_run(sc);
    const json unstarted = unstarted_report(sc, "id-1", "2026-11-26T00:00:00Z", RunStatus::Aborted, Verdict::Aborted, "cancelled while queued");
    for (const auto& [r, what] : {std::pair{&done, "finished"}, {&failed, "failed"}, {&unstarted, "unstarted"}}) {
        INFO(what);
        for (const auto& k : keys_of(*r)) {
            INFO("report key " << k);
            CHECK(documented.count(k) == 1);
        }
        for (const auto& k : documented)
            if (!optional_keys.count(k)) {
                INFO("documented key " << k);
                CHECK(r->contains(k));
            }
        CHECK((*r)["schema"] == RunReport::kSchema);
        CHECK((*r)["schema_version"] == RunReport::kSchemaVersion);
        CHECK((*r)["samples"]["planned"] == sc.samples());
    }
    CHECK(done["status"] == "done");
    CHECK(done["provenance"]["dut"]["serial"] == "SN-1");
    CHECK_FALSE(failed.contains("provenance"));
    CHECK(failed["verdict"] == "ERROR");
    CHECK(unstarted["verdict"] == "ABORTED");
    CHECK(unstarted["error"] == "cancelled while queued");
    CHECK(unstarted["estimators"].empty());
    CHECK(unstarted["device"].is_null());
    CHECK(done["estimators"].size() == sc.estimators.size());
    // A typed lane entry serialises to what the limits and the renderings read.
    RunReport typed;
    typed.scenario = sc;
    typed.verdict.reset();
    EstimatorReport lane;
    lane.label = "x";
    lane.name = "atan2";
    lane.metrics.scored = 7;
    lane.convention_violations = 2;
    lane.diagnosis.push_back({"c", "m"});
    typed.estimators.push_back(lane);
    typed.capture = json{{"path", "a.csv"}};
    const json tj = typed;
    CHECK(tj["verdict"].is_null());
    CHECK(tj["error"].is_null());
    CHECK(tj["device"].is_null());
    CHECK(tj["capture"]["path"] == "a.csv");
    CHECK(tj["estimators"][0]["metrics"]["scored"] == 7);
    CHECK(tj["estimators"][0]["metrics"]["convention_violations"] == 2);
    CHECK(tj["estimators"][0]["diagnosis"][0] == json{{"code", "c"}, {"message", "m"}});
    CHECK_FALSE(tj["estimators"][0].contains("analysers"));
    for (const auto& k : keys_of(tj)) CHECK(documented.count(k) == 1);
}

TEST_CASE("run: capture replay scores against the file's truth", "[run][capture]") {
    const auto sc0 = load_scenario(fixture("paper-duty1p6.json"));
    const std::string dir = std::filesystem::temp_directory_path() / ("fringe-run-" + std::to_string(getpid()));
    std::filesystem::create_directories(dir);
    const std::string path = dir + "/cap.fcap";
    {
        Generator g(sc0.encoder, sc0.motion, sc0.sample_rate_hz, sc0.seed);
        Block b;
        b.resize(30000, false);
        g.generate(0, b);
        json meta{{"sample_rate_hz", sc0.sample_rate_hz}, {"t0_s", 0.0}, {"encoder", sc0.encoder}};
        CaptureWriter w(path, {true, true, false}, meta);
        w.write(b);
    }
    Scenario sc = short_run();
    sc.encoder = sc0.encoder;
    sc.device = "capture:" + path;
    const json r = execute_run(sc);
    CHECK(r["status"] == "done");
    CHECK(r["samples"]["processed"] == 30000);
    CHECK(r["estimators"][1]["metrics"]["rms"]["rad"].get<double>() < 4e-5);
    std::filesystem::remove_all(dir);
}

TEST_CASE("run: scenario validation names the bad key", "[run][config]") {
    Scenario sc = short_run();
    sc.estimators[1].params = {{"natural_freq_hz", -1}};
    CHECK_THROWS_WITH(plan_run(sc), Catch::Contains("estimators[1].params.natural_freq_hz"));
    sc = short_run();
    sc.limits = {{"ekf-diffraction", "rms_radians", 1.0, std::nullopt, 0.0}};
    CHECK_THROWS_WITH(plan_run(sc), Catch::Contains("limits[0].metric") && Catch::Contains("rms_rad"));
    sc.limits = {{"ekf-magic", "rms_rad", 1.0, std::nullopt, 0.0}};
    CHECK_THROWS_WITH(plan_run(sc), Catch::Contains("limits[0].estimator"));
    json j = load_json_file(fixture("fig10c-loopback.json"));
    j["limits"][0]["maximum"] = 3;
    CHECK_THROWS_WITH(scenario_from_json(j, std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios"), Catch::Contains("limits[0].maximum"));
}

TEST_CASE("report renderings: JUnit testcases per measurement, HTML with plots", "[run][report]") {
    Scenario sc = short_run();
    const json r = execute_run(sc);
    const std::string x = junit_xml(r);
    // 4 limits plus 5 evidence checks for each of the 3 estimators
    CHECK_THAT(x, Catch::Contains("<testsuite name=\"fig10c-loopback\" tests=\"19\" failures=\"0\""));
    CHECK_THAT(x, Catch::Contains("name=\"rms_rad\""));
    CHECK_THAT(x, Catch::Contains("<property name=\"unit\" value=\"rad\"/>"));
    // every error figure with its 95 % interval, in every rendering
    CHECK_THAT(x, Catch::Contains("<property name=\"interval_95\" value=\""));
    const std::string h = report_html(r);
    std::size_t estimator_ivs = 0;
    for (auto p = h.find("id=\"estimators\""); (p = h.find("(95 % ", p + 1)) != std::string::npos;) ++estimator_ivs;
    CHECK(estimator_ivs >= r["estimators"].size());
    const auto ht = h.find("id=\"harmonics\"");
    REQUIRE(ht != std::string::npos);
    CHECK(h.find("(95 % ", ht) < h.find("</table>", ht));
    CHECK_THAT(h, Catch::Contains("Lissajous") && Catch::Contains("Error vs electrical angle") && Catch::Contains("<circle"));
    CHECK_THAT(h, Catch::Contains("<polyline") && Catch::Contains("Error harmonics"));
    // self-contained: no scripts, stylesheets or images fetched from anywhere
    CHECK(h.find("src=") == std::string::npos);
    CHECK(h.find("<link") == std::string::npos);
    CHECK(r["traces"]["t_s"].size() <= 2001);
}

namespace {
// The <svg id="ID" ...>...</svg> element of a page, or "".
std::string svg_by_id(const std::string& h, const std::string& id) {
    const auto a = h.find("<svg id=\"" + id + "\"");
    if (a == std::string::npos) return "";
    return h.substr(a, h.find("</svg>", a) + 6 - a);
}
// Every segment of every <polyline> in s: {count, longest length (SVG px)}.
std::pair<std::size_t, double> polyline_segments(const std::string& s) {
    std::size_t n = 0;
    double longest = 0;
    for (auto p = s.find("<polyline"); p != std::string::npos; p = s.find("<polyline", p + 1)) {
        const auto q = s.find("points=\"", p) + 8;
        std::istringstream pts(s.substr(q, s.find('"', q) - q));
        double x, y, px = 0, py = 0;
        char comma;
        bool first = true;
        while (pts >> x >> comma >> y) {
            if (!first) { longest = std::max(longest, std::hypot(x - px, y - py)); ++n; }
            px = x; py = y; first = false;
        }
    }
    return {n, longest};
}
}  // namespace

TEST_CASE("offline HTML: Lissajous joins only the folded cycle, error spectrum present, old reports honest", "[run][report]") {
    Scenario sc = short_run(1.0);  // stride 50: a polyline through stride samples jumps 1/19 of the circle
    const json r = execute_run(sc);
    REQUIRE(r["traces"]["kind"] == "envelope");
    const std::string h = report_html(r);
    const std::string liss = svg_by_id(h, "plot-lissajous");
    REQUIRE_FALSE(liss.empty());
    CHECK(liss.find("<circle") != std::string::npos);  // the samples, as points
    const auto [n, longest] = polyline_segments(liss);
    // The plot is 380 px with the curve's radius ~140 px: the folded cycle's 256 segments are ~3.5 px.
    CHECK(n == 256);
    CHECK(longest < 8);
    const std::string spec = svg_by_id(h, "plot-spectrum");
    REQUIRE_FALSE(spec.empty());
    CHECK(polyline_segments(spec).first > 100);
    CHECK_THAT(spec, Catch::Contains("amplitude (rad)") && Catch::Contains("frequency (Hz)") && Catch::Contains(">8x<"));
    const std::string t = svg_by_id(h, "plot-time");
    CHECK_THAT(t, Catch::Contains("<polygon") && Catch::Contains("time (s)") && Catch::Contains("error (rad)"));
    CHECK(polyline_segments(t).first == 0);  // bands, not a line through samples
    CHECK_THAT(svg_by_id(h, "plot-by-angle"), Catch::Contains("electrical angle (rad)") && Catch::Contains("<polygon"));

    // A report from before issue 11: stride samples as points, a note, and no invented spectrum.
    json old = r;
    json tr{{"stride", 50}, {"t_s", json::array()}, {"theta_true_wrapped_rad", json::array()}, {"sin_v", json::array()}, {"cos_v", json::array()}};
    json e = json::array();
    for (int i = 0; i < 2000; ++i) {
        const double th = kTwoPi * 106.7 * i * 5e-4;
        tr["t_s"].push_back(i * 5e-4);
        tr["theta_true_wrapped_rad"].push_back(wrap_pi(th));
        tr["sin_v"].push_back(0.5 * std::sin(th));
        tr["cos_v"].push_back(0.5 * std::cos(th));
        e.push_back(i % 7 ? json(1e-4 * std::sin(8 * th)) : json());
    }
    tr["error_rad"] = {{"ekf-diffraction", e}};
    old["traces"] = tr;
    for (auto& est : old["estimators"]) est.erase("spectrum");
    const std::string oh = report_html(old);
    CHECK_THAT(oh, Catch::Contains("Old report: traces are stride samples") && Catch::Contains("no spectrum in this report"));
    CHECK(polyline_segments(svg_by_id(oh, "plot-lissajous")).first == 0);
    CHECK(polyline_segments(svg_by_id(oh, "plot-time")).first == 0);
    CHECK(svg_by_id(oh, "plot-lissajous").find("<circle") != std::string::npos);
    // No traces at all (a run that processed nothing) still renders.
    old["traces"] = json::object();
    CHECK_THAT(report_html(old), Catch::Contains("No traces"));
}

TEST_CASE("run history: begin, finish, list, interrupted runs", "[store]") {
    const std::string dir = std::filesystem::temp_directory_path() / ("fringe-store-" + std::to_string(getpid()));
    std::filesystem::remove_all(dir);
    {
        SqliteStore st(dir + "/runs.db");
        Scenario sc = short_run(0.2);
        RunOptions o;
        o.run_id = "run-a";
        st.begin(o.run_id, "2026-01-01T00:00:00Z", sc.name, "");
        const json r = execute_run(sc, o);
        st.finish(r);
        // a run whose process died: pid that cannot exist
        st.begin("run-b", "2026-01-01T00:00:01Z", "dead", "");
    }
    SqliteStore st(dir + "/runs.db");
    auto rows = st.list();
    REQUIRE(rows.size() == 2);
    const auto a = st.report("run-a");
    REQUIRE(a);
    CHECK((*a)["verdict"] == "PASS");
    CHECK(st.list({"PASS", "", "", 10, "", ""}).size() == 1);
    CHECK_FALSE(st.report("run-b"));
    std::filesystem::remove_all(dir);
}

TEST_CASE("provenance helpers: SHA-256, UUIDv7, checksums, store URIs, shards", "[store]") {
    // FIPS 180-4 examples, including a message whose padding needs a second block.
    CHECK(sha256_hex("") == "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
    CHECK(sha256_hex("abc") == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    CHECK(sha256_hex("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq") == "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
    CHECK(sha256_hex(std::string(1000000, 'a')) == "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");

    std::string prev;
    for (int i = 0; i < 50; ++i) {
        const std::string id = new_run_id();
        REQUIRE(id.size() == 36);
        CHECK(id[14] == '7');                                    // version
        CHECK(std::string("89ab").find(id[19]) != std::string::npos);  // variant
        CHECK(id.substr(0, 13) >= prev.substr(0, std::min<std::size_t>(13, prev.size())));  // the millisecond prefix never goes back
        CHECK(id != prev);
        prev = id;
    }

    // The same results at another time, on another bench: the same checksum; other results: not.
    json r{{"id", "x"}, {"started_at", "2026-01-01T00:00:00Z"}, {"wall_s", 1.5}, {"verdict", "PASS"}, {"provenance", {{"bench", "a"}}}};
    json r2 = r;
    r2["started_at"] = "2027-01-01T00:00:00Z";
    r2["wall_s"] = 9.0;
    r2["provenance"]["bench"] = "b";
    CHECK(report_checksum(r) == report_checksum(r2));
    r2["verdict"] = "FAIL";
    CHECK(report_checksum(r) != report_checksum(r2));
    // As jsonb gives it back (no -0.0, no exponent: 1e+18 returns as an integer): the same checksum.
    json z{{"id", "x"}, {"v", -0.0}, {"big", 1e18}, {"half", 0.5}, {"neg", -3.0}};
    const json back = json::parse(R"({"id": "x", "v": 0, "big": 1000000000000000000, "half": 0.5, "neg": -3})");
    CHECK(report_checksum(z) == report_checksum(back));
    z["half"] = -0.5;
    CHECK(report_checksum(z) != report_checksum(back));

    CHECK(redact_store_uri("postgresql://fringe:s3cret@db:5432/runs") == "postgresql://fringe:***@db:5432/runs");
    CHECK(redact_store_uri("postgresql://db/runs?user=f&password=s3cret&sslmode=require") == "postgresql://db/runs?user=f&password=***&sslmode=require");
    CHECK(redact_store_uri("postgresql:///runs?host=/tmp/x") == "postgresql:///runs?host=/tmp/x");
    CHECK(parse_store_uri("", "/d").sqlite_path == "/d/runs.db");
    CHECK(parse_store_uri("sqlite:/x/h.db", "/d").sqlite_path == "/x/h.db");
    const auto pg = parse_store_uri("postgres://db/r", "/d");
    CHECK((pg.kind == StoreUri::Kind::Postgres && pg.sqlite_path == "/d/runs.db"));
    CHECK_THROWS_AS(parse_store_uri("mysql://db", "/d"), ConfigError);

    CHECK(parse_shard("2/3").index == 2);
    for (const char* bad : {"3/3", "1/0", "-1/3", "a/b", "1", "1/3/4", ""}) CHECK_THROWS_AS(parse_shard(bad), ConfigError);
    ::setenv("SLURM_ARRAY_TASK_ID", "5", 1);
    ::setenv("SLURM_ARRAY_TASK_COUNT", "4", 1);
    ::setenv("SLURM_ARRAY_TASK_MIN", "3", 1);  // --array=3-6
    const auto sh = shard_from_env();
    REQUIRE(sh);
    CHECK((sh->index == 2 && sh->count == 4));
    for (const char* v : {"SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT", "SLURM_ARRAY_TASK_MIN"}) ::unsetenv(v);
    ::setenv("JOB_COMPLETION_INDEX", "1", 1);
    CHECK_THROWS_AS(shard_from_env(), ConfigError);  // no count
    CHECK(shard_from_env(3)->index == 1);
    ::unsetenv("JOB_COMPLETION_INDEX");
    CHECK(!shard_from_env());

    // Deterministic sweep ids: the same file gives the same ids; another setting, other ids.
    const Sweep s = load_sweep(std::string(FRINGE_SOURCE_DIR) + "/fixtures/sweeps/table1.json");
    CHECK(sweep_run_id(s, 7) == sweep_run_id(load_sweep(std::string(FRINGE_SOURCE_DIR) + "/fixtures/sweeps/table1.json"), 7));
    CHECK(sweep_run_id(s, 7).size() == std::string("sweep-0123456789abcdef-0007").size());
    Sweep s2 = s;
    s2.base["seed"] = 2;
    CHECK(sweep_digest(s2) != sweep_digest(s));
    // Another fringe version (an upgrade), other ids: --collect never mixes versions.
    CHECK(sweep_digest(s, "0.1.0") != sweep_digest(s, "0.2.0"));
    CHECK(sweep_digest(s, "0.2.0") == sweep_digest(s, "0.2.0"));
}

TEST_CASE("run history: provenance columns, filters, the forward state, an interrupted row taken over", "[store]") {
    const std::string dir = std::filesystem::temp_directory_path() / ("fringe-prov-" + std::to_string(getpid()));
    std::filesystem::remove_all(dir);
    Scenario sc = short_run(0.2);
    sc.dut = "SN-1";
    sc.dut_part = "P-9";
    ProvenanceDefaults pd;
    pd.bench = "bench-x";
    pd.host = "h";
    pd.operator_name = "op";
    RunOptions o;
    o.run_id = "sweep-0000000000000000-0001";
    o.provenance = make_provenance(pd, sc);
    {
        SqliteStore st(dir + "/runs.db", "0123456789abcdef");
        st.set_spool(true);
        // A row left running by a process that is gone (no instance lock held): taken over.
        {
            SqliteStore gone(dir + "/runs.db", "fedcba9876543210");
            gone.begin(o.run_id, "2026-01-01T00:00:00Z", sc.name, sc.dut, "running");
        }
        st.begin(o.run_id, "2026-01-01T00:00:01Z", sc.name, sc.dut, "running", o.provenance);
        const json rep = execute_run(sc, o);
        CHECK(rep["provenance"]["dut"] == json({{"serial", "SN-1"}, {"part", "P-9"}}));
        CHECK(rep["provenance"]["scenario_sha256"] == sha256_hex(canonical_json(json(sc))));
        st.finish(rep);
        CHECK_THROWS_AS(st.begin(o.run_id, "2026-01-01T00:00:02Z", sc.name, sc.dut), StoreError);  // a reported row is never taken over
        RunFilter f;
        f.bench = "bench-x";
        REQUIRE(st.list(f).size() == 1);
        const RunRow row = st.list(f)[0];
        CHECK((row.dut == "SN-1" && row.dut_part == "P-9" && row.operator_name == "op" && row.host == "h" && row.forward == "pending"));
        f.bench = "other";
        CHECK(st.list(f).empty());
        f = {};
        f.dut = "SN-1";
        CHECK(st.list(f).size() == 1);
        REQUIRE(st.pending_forward(10).size() == 1);
        st.set_forwarded(o.run_id, "done");
        CHECK(st.pending_count() == 0);
        CHECK(st.row(o.run_id)->forward == "done");
    }
    std::filesystem::remove_all(dir);
}

TEST_CASE("store URIs: passwords redacted however they are written, and URIs libpq would misread refused by name", "[store][redact]") {
    // A raw '/' or '@' in the password: everything up to the last '@' is hidden.
    CHECK(redact_store_uri("postgresql://f:pa/ss@db/runs") == "postgresql://f:***@db/runs");
    CHECK(redact_store_uri("postgresql://f:p@ss@db/runs") == "postgresql://f:***@db/runs");
    CHECK(redact_store_uri("postgresql://f:p%zz@db/runs") == "postgresql://f:***@db/runs");
    // A percent-encoded key, any case; a value holding '&' runs to the next key.
    CHECK(redact_store_uri("postgresql:///r?host=/tmp&%70assword=s3/cret&user=f") == "postgresql:///r?host=/tmp&%70assword=***&user=f");
    CHECK(redact_store_uri("postgresql:///r?PASSWORD=a&b&user=f") == "postgresql:///r?PASSWORD=***&user=f");
    CHECK(redact_store_uri("postgresql:///r?pass%77ord=x%zz") == "postgresql:///r?pass%77ord=***");
    // key=value conninfo text, quoted or not.
    CHECK(redact_store_uri("host=db password='se cr\\'et' user=f") == "host=db password=*** user=f");
    CHECK(redact_store_uri("host=db password=s3cret user=f") == "host=db password=*** user=f");
    // Any text: the URI, and the password wherever libpq quotes it (encoded or decoded).
    const std::string uri = "postgresql://f:s%2Fcr%40t@db/runs";
    CHECK(redact_store_text("run store " + uri + ": bad token \"s%2Fcr%40t\" or \"s/cr@t\"", uri) ==
          "run store postgresql://f:***@db/runs: bad token \"***\" or \"***\"");
    CHECK(store_uri_problem(uri).empty());
    CHECK(store_uri_problem("postgresql:///runs?host=/tmp/x&user=a@b").empty());
    CHECK(store_uri_problem("postgresql://f:p%zz@db/r").find("%25") != std::string::npos);
    CHECK(store_uri_problem("postgresql://f:p@ss@db/r").find("%40") != std::string::npos);
    CHECK(store_uri_problem("postgresql://f:pa/ss@db/r").find("%2F") != std::string::npos);
    CHECK(store_uri_problem("postgresql://f:pa/ss@db/r").find("pa/ss") == std::string::npos);
    try {
        parse_store_uri("postgresql://f:pa/ss@db/r", "/d");
        FAIL("accepted");
    } catch (const ConfigError& e) {
        CHECK(std::string(e.what()).find("pa/ss") == std::string::npos);
        CHECK(std::string(e.what()).find("%2F") != std::string::npos);
    }
}

}  // namespace test_run_cpp
