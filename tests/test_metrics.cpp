// The metric table (server/analysis/metrics.hpp) is the one description of every metric: each
// rendering of a report shows every metric of the table with its unit, GET /schema and
// docs/schema.md carry the table itself, and a limit may only name what the table allows.
#include "helpers.hpp"

#include "server/analysis/metrics.hpp"
#include "server/engine/plan.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/engine/schema_info.hpp"
#include "server/report/report_formats.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/constants.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_metrics_cpp {

using namespace fringe;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

std::string read_file(const fs::path& p) {
    std::ifstream f(p);
    std::stringstream s;
    s << f.rdbuf();
    return s.str();
}

std::string run_command(const std::string& cmd) {
    std::string out;
    FILE* p = popen(cmd.c_str(), "r");
    REQUIRE(p);
    char buf[4096];
    while (std::size_t n = std::fread(buf, 1, sizeof buf, p)) out.append(buf, n);
    pclose(p);
    return out;
}

// A value as the CLI summary prints it.
std::string fmt_cli(double v) {
    char b[40];
    if (v == std::floor(v) && std::fabs(v) < 1e15) std::snprintf(b, sizeof b, "%.0f", v);
    else if (std::fabs(v) >= 1e-2 && std::fabs(v) < 1e5) std::snprintf(b, sizeof b, "%.4g", v);
    else std::snprintf(b, sizeof b, "%.3e", v);
    return b;
}

// Two lanes (one with a rate estimate, one without), a limit, 0.3 s of ideal quadrature.
json metrics_scenario() {
    return json{{"name", "metrics"},
                {"encoder", std::string(FRINGE_SOURCE_DIR) + "/fixtures/encoders/ideal.json"},
                {"motion", {{"kind", "constant"}, {"electrical_freq_hz", 50.0}}},
                {"sample_rate_hz", 20000},
                {"duration_s", 0.3},
                {"seed", 11},
                {"settle_s", 0.05},
                {"device", "loopback:?dac_bits=16&adc_bits=16"},
                {"estimators", json::array({json{{"name", "atan2"}}, json{{"name", "pll2"}, {"params", {{"natural_freq_hz", 50}}}}})},
                {"limits", json::array({json{{"estimator", "*"}, {"metric", "rms_rad"}, {"max", 0.1}}})}};
}

}  // namespace

TEST_CASE("metrics: every metric of the table appears, with its unit, in every rendering", "[metrics][report]") {
    test::TempDir d("fringe-metrics");
    const fs::path scen = d.path / "metrics.json", rep = d.path / "r.json";
    std::ofstream(scen) << metrics_scenario().dump(2);
    // The CLI, the built executable: summary and --metrics, and the report it writes.
    const std::string out = run_command(std::string(FRINGE_CLI) + " run " + scen.string() + " --no-db --metrics --report " + rep.string() +
                                        " --junit " + (d.path / "r.xml").string() + " --html " + (d.path / "r.html").string() + " 2>&1");
    const json r = json::parse(read_file(rep));
    REQUIRE(r["status"] == "done");
    const std::string junit = read_file(d.path / "r.xml"), html = read_file(d.path / "r.html");
    const json schema = scenario_schema()["metrics"], per_lane = report_metrics_json(r);
    const std::string docs = read_file(fs::path(FRINGE_SOURCE_DIR) / "docs" / "schema.md");
    const std::vector<std::string> lanes{"atan2", "pll2"};
    INFO(out);

    std::size_t measured = 0, not_measured = 0;
    for (const auto& m : metric_catalog()) {
        INFO(m.name);
        // GET /schema and `fringe metrics --json`: the table itself.
        bool in_schema = false;
        for (const auto& s : schema) in_schema = in_schema || (s["name"] == m.name && s["unit"] == m.unit && s["limitable"] == m.limitable);
        CHECK(in_schema);
        // docs/schema.md: the table's row with its unit ("1" for a ratio).
        CHECK(docs.find("| `" + m.name + "` | " + (m.unit.empty() ? "1" : m.unit) + " |") != std::string::npos);
        // HTML: the all-metrics table's row names the metric and its unit.
        CHECK(html.find("<tr><td><code>" + m.name + "</code></td><td>" + m.unit + "</td>") != std::string::npos);
        // GET runs/{id}/metrics (the web's tables): the metric with its unit, a value or a reason per lane.
        bool in_lanes = false;
        for (const auto& x : per_lane["metrics"])
            if (x["name"] == m.name && x["unit"] == m.unit) {
                in_lanes = true;
                for (const auto& l : m.run_level ? std::vector<std::string>{"run"} : lanes) {
                    REQUIRE(x["values"].contains(l));
                    const json& v = x["values"][l];
                    CHECK((v["value"].is_number() || (v["value"].is_null() && v["why"].is_string() && !v["why"].get<std::string>().empty())));
                }
            }
        CHECK(in_lanes);
        for (const auto& l : m.run_level ? std::vector<std::string>{"run"} : lanes) {
            std::string why;
            const auto v = m.run_level ? run_metric_value(m.name, r, &why)
                                       : metric_value(m.name, r["estimators"][l == "atan2" ? 0 : 1]["metrics"], r["estimators"][l == "atan2" ? 0 : 1]["bounds"], &why);
            (v ? measured : not_measured) += 1;
            // JUnit: a suite property per lane and metric; a measured value carries its unit.
            const std::string key = "name=\"metric." + l + "." + m.name + "\" value=\"";
            const auto at = junit.find(key);
            REQUIRE(at != std::string::npos);
            const std::string value = junit.substr(at + key.size(), junit.find('"', at + key.size()) - at - key.size());
            if (v && !m.unit.empty()) CHECK(value.find(" " + m.unit) != std::string::npos);
            if (!v) CHECK(value.rfind("not measured: ", 0) == 0);
            // CLI --metrics: a line per lane and metric, with the unit when measured.
            const std::string lane_block = out.substr(out.find("\n" + l + ":\n") == std::string::npos ? 0 : out.find("\n" + l + ":\n"));
            const auto line_at = lane_block.find("  " + m.name + " ");
            REQUIRE(line_at != std::string::npos);
            const std::string line = lane_block.substr(line_at, lane_block.find('\n', line_at) - line_at);
            if (v && !m.unit.empty()) CHECK(line.find(" " + m.unit) != std::string::npos);
            if (!v) CHECK(line.find("not measured: " + why) != std::string::npos);
        }
    }
    // The run measured most of the table and said why for the rest (no alignment, no ABZ DUT).
    CHECK(measured > 40);
    CHECK(not_measured > 0);
    // The summary columns: headings with units in the HTML estimators table, and in the CLI's
    // one line per estimator each measured column with its unit.
    for (const auto* m : summary_metrics()) {
        INFO(m->name);
        std::string head = ">";
        head += xml_escape(m->column);
        if (!m->unit.empty()) head.append(" (").append(m->unit).append(")");
        head += "</th>";
        CHECK(html.find(head) != std::string::npos);
        const auto v = m->value(r["estimators"][0], nullptr);
        const auto from = out.find("  atan2 "), to = out.find("  pll2 ");
        REQUIRE(from != std::string::npos);
        REQUIRE(to != std::string::npos);
        const std::string block = out.substr(from, to - from);  // atan2's summary lines
        if (v) CHECK(block.find(m->column + " ") != std::string::npos);
        if (v && !m->unit.empty()) CHECK(block.find(m->column + " " + fmt_cli(*v) + " " + m->unit) != std::string::npos);
    }
}

TEST_CASE("metrics: docs/schema.md holds the table as fringe metrics --markdown prints it", "[metrics][docs]") {
    const std::string docs = read_file(fs::path(FRINGE_SOURCE_DIR) / "docs" / "schema.md");
    const std::string begin = "<!-- metrics:begin (generated by `fringe metrics --markdown`; a test checks it) -->\n", end = "<!-- metrics:end -->";
    const auto a = docs.find(begin), b = docs.find(end);
    REQUIRE(a != std::string::npos);
    REQUIRE(b != std::string::npos);
    CHECK(docs.substr(a + begin.size(), b - a - begin.size()) == metric_table_markdown());
    CHECK(run_command(std::string(FRINGE_CLI) + " metrics --markdown") == metric_table_markdown());
    CHECK(json::parse(run_command(std::string(FRINGE_CLI) + " metrics --json")) == metric_table_json());
}

TEST_CASE("metrics: the table's getters read the report where its figures are, and say why when they cannot", "[metrics]") {
    // Hand-made report entries: each getter against the figure it must find.
    const json e{{"label", "x"},
                 {"metrics", {{"rms", {{"rad", 2e-3}, {"percent_period", 2e-3 / kTwoPi * 100}}},
                              {"max_abs", {{"rad", 5e-3}}},
                              {"uncertainty", {{"rms_rad", {1.9e-3, 2.1e-3}}}},
                              {"evidence", {{"scored_samples", 1234}, {"valid_fraction", 0.5}}},
                              {"harmonics", json::array({json{{"order", 3}, {"amplitude", {{"rad", 7e-4}}}}})}}},
                 {"bounds", {{"pcrb_rad", 1e-4}, {"efficiency", 0.25}}}};
    auto get = [&](const char* name) { return find_metric(name)->value(e, nullptr); };
    CHECK(get("rms_rad").value() == 2e-3);
    CHECK(get("max_abs_rad").value() == 5e-3);
    CHECK(get("scored_samples").value() == 1234);
    CHECK(get("valid_fraction").value() == 0.5);
    CHECK(get("harmonic_3x_rad").value() == 7e-4);
    CHECK(get("pcrb_rad").value() == 1e-4);
    CHECK(get("efficiency").value() == 0.25);
    // The same interval in other units scales with the figure: % of a period = rad / 2 pi * 100.
    const auto iv = find_metric("rms_percent_period")->interval(e, 2e-3 / kTwoPi * 100);
    REQUIRE(iv);
    CHECK(iv->first == Approx(1.9e-3 / kTwoPi * 100));
    CHECK(iv->second == Approx(2.1e-3 / kTwoPi * 100));
    // efficiency = bound / rms^2: a larger rms gives a smaller efficiency.
    const auto ie = find_metric("efficiency")->interval(e, 0.25);
    REQUIRE(ie);
    CHECK(ie->first == Approx(0.25 * (2.0 / 2.1) * (2.0 / 2.1)));
    CHECK(ie->second == Approx(0.25 * (2.0 / 1.9) * (2.0 / 1.9)));
    std::string why;
    CHECK_FALSE(find_metric("harmonic_5x_rad")->value(e, &why));
    CHECK(why.find("5x") != std::string::npos);
    CHECK_FALSE(find_metric("lock_time_s")->value(e, &why));
    CHECK(why.find("never locked") != std::string::npos);
    CHECK_FALSE(find_metric("alignment_delay_s")->value(json(), &why));
    CHECK(why.find("no alignment") != std::string::npos);
}

TEST_CASE("metrics: a limit may name only what the table allows", "[metrics][config]") {
    json j = metrics_scenario();
    j["limits"] = json::array({json{{"estimator", "*"}, {"metric", "pcrb_rad"}, {"max", 1.0}}});
    const Scenario sc = scenario_from_json(j, std::string(FRINGE_SOURCE_DIR) + "/fixtures/encoders");
    try {
        plan_run(sc);
        FAIL("a limit on a bound was accepted");
    } catch (const ConfigError& e) {
        CHECK(std::string(e.what()).find("limits[0].metric") != std::string::npos);
        CHECK(std::string(e.what()).find("bound of the signal") != std::string::npos);
    }
}

TEST_CASE("metrics: reserved labels, an empty limit band and a non-finite figure are refused or not measured", "[metrics][config]") {
    const std::string enc = std::string(FRINGE_SOURCE_DIR) + "/fixtures/encoders";
    for (const char* label : {"run", "*", "dut", ""}) {
        INFO("label '" << label << "'");
        json j = metrics_scenario();
        j["estimators"][0]["label"] = label;
        CHECK_THROWS_WITH(scenario_from_json(j, enc), Catch::Contains("estimators[0].label") && Catch::Contains("reserved"));
    }
    json j = metrics_scenario();
    j["limits"] = json::array({json{{"estimator", "run"}, {"metric", "signal_phase_deg"}, {"min", 95.5}, {"max", 94.0}}});
    CHECK_THROWS_WITH(scenario_from_json(j, enc), Catch::Contains("limits[0].min") && Catch::Contains("no value could pass"));
    j["limits"] = json::array({json{{"estimator", "run"}, {"metric", "rms_rad"}, {"max", 1.0}}});
    CHECK_THROWS_WITH(plan_run(scenario_from_json(j, enc)), Catch::Contains("a figure of each estimator, not of the run"));
    // An overflowed figure (NaN or inf in memory, null once stored) is not measured, so its limit FAILs.
    std::string why;
    CHECK_FALSE(run_metric_value("signal_sym_a", json{{"signal", {{"periods", 3}, {"a", {{"sym", std::nan("")}}}}}}, &why));
    CHECK(why.find("not finite") != std::string::npos);
    CHECK_FALSE(run_metric_value("signal_ab_ratio", json{{"signal", {{"periods", 3}, {"ab_ratio", HUGE_VAL}}}}, &why));
    CHECK_FALSE(metric_value("rms_rad", json{{"rms", {{"rad", std::nan("")}}}}, json()));
}

}  // namespace test_metrics_cpp
