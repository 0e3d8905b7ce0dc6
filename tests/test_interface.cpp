// Interface profiles (server/engine/interface_profile.hpp, docs/signal-quality.md): parsing and
// its refusals, the fixtures, the bands' edges, and runs graded against 1 Vpp.
#include "helpers.hpp"

#include "server/engine/interface_profile.hpp"
#include "server/report/report_formats.hpp"
#include "server/engine/limits.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/base/config.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_interface_cpp {

using namespace fringe;
using nlohmann::json;

namespace {
const std::string kScenarios = FRINGE_SOURCE_DIR "/fixtures/scenarios";

json band_profile(json bands) { return json{{"name", "test"}, {"bands", std::move(bands)}}; }

std::string refusal(const json& j) {
    try {
        interface_from_json(j, "interface");
    } catch (const ConfigError& e) {
        return e.field() + ": " + e.what();
    }
    return "";
}

// One measurement of the profile's band for `metric` on a run whose signal figures are `signal`.
json graded(const json& bands, const json& signal) {
    Scenario sc;
    sc.interface = interface_from_json(band_profile(bands), "interface");
    Verdict v;
    const json out = evaluate_limits(sc, json::array(), RunStatus::Done, v, json{{"alignment", nullptr}, {"signal", signal}});
    REQUIRE(out.size() == 1);
    return out[0];
}
}  // namespace

TEST_CASE("interface: a profile's refusals name the field", "[interface][config]") {
    CHECK_THAT(refusal(json::array()), Catch::Contains("expected an interface profile object"));
    CHECK_THAT(refusal(band_profile(json::object())), Catch::Contains("interface.bands") && Catch::Contains("no bands"));
    json stray = band_profile(json::object());
    stray["zz"] = 1;  // the unknown key is named, not the empty bands it came with
    CHECK_THAT(refusal(stray), Catch::Contains("interface.zz") && Catch::Contains("unknown key"));
    CHECK_THAT(refusal(band_profile({{"rms_rad", {{"spec", {0, 1}}}}})), Catch::Contains("not a signal-quality metric"));
    CHECK_THAT(refusal(band_profile({{"signal_ab_ratio", {{"spec", {1.25, 0.8}}}}})), Catch::Contains("interface.bands.signal_ab_ratio.spec: lo is above hi"));
    CHECK_THAT(refusal(band_profile({{"signal_ab_ratio", {{"spec", {nullptr, nullptr}}}}})), Catch::Contains("at least one side"));
    CHECK_THAT(refusal(band_profile({{"signal_ab_ratio", {{"spec", {0.8}}}}})), Catch::Contains("expected [lo, hi]"));
    CHECK_THAT(refusal(band_profile({{"signal_ab_ratio", {{"spec", {0.8, "x"}}}}})), Catch::Contains("finite number or null"));
    CHECK_THAT(refusal(band_profile({{"signal_ab_ratio", {{"spec", {0.8, 1.25}}, {"mounting", {0.7, 1.1}}}}})),
               Catch::Contains("mounting tolerance must lie inside"));
    CHECK_THAT(refusal(band_profile({{"signal_sym_a", {{"spec", {nullptr, 0.065}}, {"mounting", {nullptr, 0.1}}}}})),
               Catch::Contains("mounting tolerance must lie inside"));
    CHECK_THAT(refusal(band_profile({{"signal_ab_ratio", {{"spec", {0.8, 1.25}}, {"extra", 1}}}})), Catch::Contains("extra"));
    json unknown = band_profile({{"signal_ab_ratio", {{"spec", {0.8, 1.25}}}}});
    unknown["colour"] = "green";
    CHECK_THAT(refusal(unknown), Catch::Contains("colour"));
    json unnamed = band_profile({{"signal_ab_ratio", {{"spec", {0.8, 1.25}}}}});
    unnamed["name"] = "";
    CHECK_THAT(refusal(unnamed), Catch::Contains("name"));
}

TEST_CASE("interface: the fixtures parse, a scenario names one by path and carries it inline", "[interface][config]") {
    for (const char* f : {"1vpp.json", "11uapp-100k.json"}) {
        INFO(f);
        const auto p = interface_from_json(load_json_file(std::string(FRINGE_SOURCE_DIR "/fixtures/interfaces/") + f), "interface");
        CHECK(p.bands.size() == 6);
        CHECK_FALSE(p.source.empty());
    }
    json j = load_json_file(kScenarios + "/fig10c-loopback.json");
    j["interface"] = "../interfaces/1vpp.json";
    const Scenario sc = scenario_from_json(j, kScenarios);
    REQUIRE(sc.interface);
    CHECK(sc.interface->name == "1 Vpp");
    const json inline_j = sc;  // as run: the profile inline
    CHECK(inline_j["interface"]["bands"]["signal_ab_ratio"]["spec"] == json::array({0.8, 1.25}));
    const Scenario again = scenario_from_json(inline_j, kScenarios);
    REQUIRE(again.interface);
    CHECK(json(*again.interface) == json(*sc.interface));
    j["interface"] = "../interfaces/none.json";
    CHECK_THROWS_AS(scenario_from_json(j, kScenarios), ConfigError);
    j["interface"] = 3;
    CHECK_THROWS_AS(scenario_from_json(j, kScenarios), ConfigError);
}

TEST_CASE("interface: the bands' edges: mounting PASS, specification MARGINAL, outside or not measured FAIL", "[interface][limits]") {
    const json bands{{"signal_ab_ratio", {{"spec", {0.8, 1.25}}, {"mounting", {0.9, 1.1}}}}};
    auto at = [&](double ratio) { return graded(bands, json{{"periods", 10}, {"ab_ratio", ratio}}); };
    CHECK(at(1.0)["outcome"] == "PASS");
    CHECK(at(1.1)["outcome"] == "PASS");  // the edges belong to the band
    CHECK(at(0.9)["outcome"] == "PASS");
    CHECK(at(1.1000001)["outcome"] == "MARGINAL");
    CHECK(at(1.25)["outcome"] == "MARGINAL");
    CHECK(at(0.8)["outcome"] == "MARGINAL");
    CHECK(at(1.2500001)["outcome"] == "FAIL");
    CHECK(at(0.7999999)["outcome"] == "FAIL");
    CHECK(at(1.0)["grade"] == "within mounting tolerance");
    CHECK(at(1.2)["grade"] == "within specification, outside mounting tolerance");
    CHECK(at(2.0)["grade"] == "out of specification");
    CHECK(at(1.0)["interface"] == "test");
    CHECK(at(1.0)["band"]["mounting"] == json::array({0.9, 1.1}));
    // Not measured (no whole period): FAIL with the reason, never a 0 that passes.
    const json none = graded(bands, json{{"periods", 0}, {"note", "no whole electrical period"}});
    CHECK(none["outcome"] == "FAIL");
    CHECK(none["value"].is_null());
    CHECK_THAT(none["reason"].get<std::string>(), Catch::Contains("no whole electrical period"));
    // One-sided: SYM at most 0.065.
    const json sym{{"signal_sym_a", {{"spec", {nullptr, 0.065}}}}};
    CHECK(graded(sym, json{{"periods", 3}, {"a", {{"sym", 0.0}}}})["outcome"] == "PASS");
    CHECK(graded(sym, json{{"periods", 3}, {"a", {{"sym", 0.07}}}})["outcome"] == "FAIL");
}

TEST_CASE("interface: runs graded against 1 Vpp: nominal PASS, 2 Vpp FAIL, an A/B ratio outside mounting MARGINAL", "[interface][run]") {
    auto run = [](double vmax_v, double gain_mismatch) {
        const json j{{"name", "graded"},
                     {"encoder", {{"name", "e"}, {"model", "ideal"}, {"lines_per_rev", 1024}, {"vmax_v", vmax_v}, {"noise", {{"sigma_add_v", 2e-4}}},
                                  {"lissajous", {{"gain_mismatch", gain_mismatch}}}}},
                     {"motion", {{"kind", "constant"}, {"electrical_freq_hz", 200.0}}},
                     {"sample_rate_hz", 50000}, {"duration_s", 0.3}, {"settle_s", 0.05}, {"seed", 2},
                     {"device", "loopback:?dac_bits=16&adc_bits=16"}, {"interface", "../interfaces/1vpp.json"},
                     {"estimators", json::array({json{{"name", "atan2"}}})}};
        return json(execute_run(scenario_from_json(j, kScenarios)));
    };
    auto outcome = [](const json& r, const std::string& metric) {
        for (const auto& m : r["measurements"])
            if (m["metric"] == metric && m.contains("interface")) return m["outcome"].get<std::string>();
        return std::string("absent");
    };
    const json nominal = run(0.5, 0.0);
    CHECK(nominal["verdict"] == "PASS");
    for (const char* m : {"signal_vpp_a_v", "signal_vpp_b_v", "signal_ab_ratio", "signal_phase_deg", "signal_tv_a_deg", "signal_tv_b_deg"})
        CHECK(outcome(nominal, m) == "PASS");
    const json big = run(1.0, 0.0);
    CHECK(big["verdict"] == "FAIL");
    CHECK(outcome(big, "signal_vpp_a_v") == "FAIL");
    const json skewed = run(0.5, 0.15);  // A/B = 1.075 / 0.925 = 1.16
    CHECK(outcome(skewed, "signal_ab_ratio") == "MARGINAL");
    CHECK(skewed["verdict"] == "MARGINAL");
}

TEST_CASE("interface: the HTML report's signal section: a gauge a band with its grade, the 1:1 Lissajous with rings, the trends against the bands", "[interface][report]") {
    auto run = [](double vmax_v, bool with_interface, double duration_s = 0.3) {
        json j{{"name", "graded"},
               {"encoder", {{"name", "e"}, {"model", "ideal"}, {"lines_per_rev", 1024}, {"vmax_v", vmax_v}, {"noise", {{"sigma_add_v", 2e-4}}}}},
               {"motion", {{"kind", "constant"}, {"electrical_freq_hz", 200.0}}},
               {"sample_rate_hz", 50000}, {"duration_s", duration_s}, {"settle_s", 0.0}, {"seed", 2},
               {"device", "loopback:?dac_bits=16&adc_bits=16"},
               {"estimators", json::array({json{{"name", "atan2"}}})}};
        if (with_interface) j["interface"] = "../interfaces/1vpp.json";
        return json(execute_run(scenario_from_json(j, kScenarios)));
    };
    auto count = [](const std::string& s, const std::string& what) {
        std::size_t n = 0;
        for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + 1)) ++n;
        return n;
    };
    const json graded_run = run(1.0, true);  // 2 Vpp: amplitude out of specification, the rest within mounting
    const std::string html = report_html(graded_run);
    REQUIRE(html.find("<div id=\"signal-page\">") != std::string::npos);
    CHECK(html.find("Graded against <b>1 Vpp</b>") != std::string::npos);
    // One gauge a band, its outcome the measurement's.
    std::size_t bands = 0;
    for (const auto& m : graded_run["measurements"]) {
        if (!m.contains("interface")) continue;
        ++bands;
        INFO(m.dump());
        CHECK(html.find("class=\"gauge\" data-metric=\"" + m["metric"].get<std::string>() + "\" data-outcome=\"" + m["outcome"].get<std::string>() + "\"") !=
              std::string::npos);
    }
    CHECK(bands == 6);
    CHECK(count(html, "class=\"gauge\"") == 6);
    CHECK(html.find("data-metric=\"signal_vpp_a_v\" data-outcome=\"FAIL\"") != std::string::npos);
    CHECK(html.find("data-metric=\"signal_phase_deg\" data-outcome=\"PASS\"") != std::string::npos);
    // The Lissajous is square (1:1) and has the four rings of 0.6/0.8/1.1/1.2 Vpp.
    const auto lp = html.find("<svg id=\"plot-signal-lissajous\"");
    REQUIRE(lp != std::string::npos);
    const std::string liss = html.substr(lp, html.find("</svg>", lp) - lp);
    CHECK(liss.find("width=\"420\" height=\"" + std::to_string(static_cast<int>(420 - 70 - 12 + 46 + 40)) + "\"") != std::string::npos);
    CHECK(count(liss, "stroke=\"#bf8700\"") >= 2);  // two specification rings (and the legend)
    CHECK(count(liss, "<polyline") == 4 + 3);      // four rings, the spread's two edges, the mean
    for (const char* id : {"plot-signal-vpp", "plot-signal-ratio", "plot-signal-phase", "plot-signal-tv"})
        CHECK(html.find(std::string("<svg id=\"") + id + "\"") != std::string::npos);
    CHECK(html.find("spec 1.2") != std::string::npos);  // the band's edge on the amplitude trend
    // Against the shaft angle: one point a recorded period and channel (1024 lines: a point's angle is its period's place mod 1024).
    const auto sp = html.find("<svg id=\"plot-signal-shaft\"");
    REQUIRE(sp != std::string::npos);
    const std::string shaft = html.substr(sp, html.find("</svg>", sp) - sp);
    CHECK(count(shaft, "<circle") == 2 * graded_run["signal"]["recording"]["first_period"].size());
    CHECK(shaft.find("1024 periods a revolution") != std::string::npos);
    // And as a table: a row a recorded period, under its header row.
    const auto tp = html.find("<details id=\"signal-recording\">");
    REQUIRE(tp != std::string::npos);
    const std::string table = html.substr(tp, html.find("</details>", tp) - tp);
    CHECK(count(table, "<tr>") == 1 + graded_run["signal"]["recording"]["first_period"].size());
    SECTION("without a profile: not graded, no rings, said so") {
        const std::string plain = report_html(run(0.5, false));
        CHECK(plain.find("No interface profile: the figures are not graded") != std::string::npos);
        CHECK(plain.find("class=\"gauge\"") == std::string::npos);
        CHECK(plain.find("no tolerance rings") != std::string::npos);
    }
    SECTION("no whole period: the analyser's note, nothing drawn, every band not measured") {
        const json short_run = run(0.5, true, 0.004);  // 0.8 of a period
        const std::string s = report_html(short_run);
        CHECK(s.find("id=\"signal-note\">Signals not analysed: ") != std::string::npos);
        CHECK(s.find("plot-signal-lissajous") == std::string::npos);
        CHECK(short_run["verdict"] != "PASS");
    }
}

TEST_CASE("a lane told another amplitude than the signals have is warned amplitude_mismatch (estimators whose model takes it from the profile)", "[interface][run][preflight]") {
    // Signals of 0.5 V peak; ekf-ideal told a 1 V profile (its default), atan2 and ekf-selfcal
    // (no amplitude from the profile) not warned; ekf-ideal told the signals' own profile not warned.
    const json signals{{"name", "half"}, {"model", "ideal"}, {"lines_per_rev", 1024}, {"vmax_v", 0.5}, {"noise", {{"sigma_add_v", 2e-4}}}};
    json told = signals;
    told["vmax_v"] = 1.0;
    const json j{{"name", "amplitude"}, {"encoder", signals}, {"motion", {{"kind", "constant"}, {"electrical_freq_hz", 200.0}}},
                 {"sample_rate_hz", 50000}, {"duration_s", 0.2}, {"settle_s", 0.05}, {"seed", 3},
                 {"device", "loopback:?dac_bits=16&adc_bits=16"},
                 {"estimators", json::array({json{{"name", "ekf-ideal"}, {"label", "told-1V"}, {"encoder", told}},
                                             json{{"name", "ekf-ideal"}, {"label", "told-right"}}, json{{"name", "atan2"}, {"encoder", told}},
                                             json{{"name", "ekf-selfcal"}, {"encoder", told}}})}};
    const json r = execute_run(scenario_from_json(j, kScenarios));
    REQUIRE(r["status"] == "done");
    std::vector<std::string> warned;
    for (const auto& w : r["warnings"])
        if (w["code"] == "amplitude_mismatch") {
            warned.push_back(w["field"].get<std::string>());
            CHECK_THAT(w["message"].get<std::string>(), Catch::Contains("told-1V is told a signal of 1 V peak") && Catch::Contains("measure 0.5 V peak"));
        }
    CHECK(warned == std::vector<std::string>{"estimators[0]"});
}

}  // namespace test_interface_cpp
