// Strict configuration: unknown keys, wrong types and out-of-range values name the key;
// the fixtures load; profiles survive a JSON round trip.
#include "server/engine/scenario.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/ring.hpp"
#include "signal_gen/optics.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <deque>
#include <limits>
#include <vector>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_config_cpp {

using namespace fringe;
using nlohmann::json;
using Catch::Matchers::WithinAbs;

namespace {
const std::string kSrc = FRINGE_SOURCE_DIR;

std::string field_of(const json& j) {
    try {
        encoder_from_json(j);
    } catch (const ConfigError& e) {
        return e.field();
    }
    return "<no error>";
}
}  // namespace

TEST_CASE("encoder profile errors name the key", "[config]") {
    json base = {{"name", "x"}, {"model", "diffraction"}, {"optics", {{"aperture_w_rad", 2.0}}}};
    CHECK(field_of(base) == "<no error>");
    json j = base;
    j["optics"]["aperture_w"] = 2.0;
    CHECK(field_of(j) == "encoder.optics.aperture_w");
    j = base;
    j["noise"] = {{"sigma_add_v", "loud"}};
    CHECK(field_of(j) == "encoder.noise.sigma_add_v");
    j = base;
    j["adc"] = {{"bits", 40}};
    CHECK(field_of(j) == "encoder.adc.bits");
    j = base;
    j["adc"] = {{"bits", 12}, {"min_v", 1.0}, {"max_v", -1.0}};
    CHECK(field_of(j) == "encoder.adc.max_v");
    j = base;
    j["model"] = "hologram";
    CHECK(field_of(j) == "encoder.model");
    j = base;
    j["lines_per_rev"] = 10.5;
    CHECK(field_of(j) == "encoder.lines_per_rev");
    j = base;
    j["harmonics"] = json::array();
    CHECK(field_of(j) == "encoder.harmonics");  // only for the ideal model
    j = {{"model", "ideal"}, {"harmonics", {{{"order", 1}, {"amplitude_rel", 0.1}}}}};
    CHECK(field_of(j) == "encoder.harmonics[0].order");
    try {
        encoder_from_json(json{{"noise", {{"sigma_gain", 2.0}}}});
        FAIL("no error");
    } catch (const ConfigError& e) {
        CHECK_THAT(e.what(), Catch::Contains("out of range"));
    }
}

TEST_CASE("fixtures load with the documented parameters", "[config][fixtures]") {
    EncoderProfile p = load_encoder(kSrc + "/fixtures/encoders/paper-d2-duty1p6.json");
    CHECK_THAT(p.kappa_nominal(), WithinAbs(1.1149, 1e-4));
    CHECK(p.aperture_w_rad == 2.8713);
    CHECK_THAT(p.reference_v(), WithinAbs(2.8713 / 2, 1e-15));
    CHECK(p.adc.bits == 16);
    CHECK(p.noise.sigma_add_v == 2e-4);
    CHECK(p.noise.sigma_gain == 1e-4);
    EncoderProfile id = load_encoder(kSrc + "/fixtures/encoders/ideal.json");
    CHECK(id.model == ModelKind::Ideal);
    CHECK(id.fundamental_amplitude_v() == 1.0);
    CHECK(id.reference_v() == 0.0);

    Scenario s = load_scenario(kSrc + "/fixtures/scenarios/paper-duty1p6.json");
    CHECK(s.samples() >= 60000);
    CHECK(s.encoder.lines_per_rev == 1024);
    // 937 samples per electrical cycle at 100 kHz
    const double cycle_samples = s.sample_rate_hz / (s.motion.velocity_rad_s * 1024 / (2 * 3.141592653589793));
    CHECK_THAT(cycle_samples, WithinAbs(937.0, 1e-9));
}

TEST_CASE("profiles and scenarios round-trip through JSON", "[config]") {
    Scenario s = load_scenario(kSrc + "/fixtures/scenarios/paper-duty1p6.json");
    json j = s;
    Scenario t = scenario_from_json(j, "");
    CHECK(json(t) == j);
}

TEST_CASE("scenario errors name the key", "[config]") {
    json j = load_json_file(kSrc + "/fixtures/scenarios/paper-duty1p6.json");
    j["encoder"] = load_json_file(kSrc + "/fixtures/encoders/ideal.json");
    CHECK_NOTHROW(scenario_from_json(j, ""));
    json bad = j;
    bad["sample_rate"] = 1;
    CHECK_THROWS_WITH(scenario_from_json(bad, ""), "sample_rate: unknown key");
    bad = j;
    bad["motion"]["kind"] = "warp";
    CHECK_THROWS_WITH(scenario_from_json(bad, ""), Catch::StartsWith("motion.kind:"));
    bad = j;
    bad.erase("motion");
    CHECK_THROWS_WITH(scenario_from_json(bad, ""), "motion: required key is missing");
    bad = j;
    bad["encoder"] = "does-not-exist.json";
    CHECK_THROWS_WITH(scenario_from_json(bad, "/tmp"), Catch::Contains("cannot open"));
    CHECK_THROWS_AS(load_json_file(kSrc + "/README.md"), ConfigError);
    // a name that resolves to a folder (found by fuzz_config: "encoder": "")
    bad["encoder"] = "";
    CHECK_THROWS_WITH(scenario_from_json(bad, kSrc + "/fixtures"), Catch::Contains("is a directory"));
    CHECK_THROWS_AS(load_json_file(kSrc + "/fixtures"), ConfigError);
}

TEST_CASE("scenario seed is an integer in [0, 2^53], checked exactly", "[config]") {
    json j = load_json_file(kSrc + "/fixtures/scenarios/paper-duty1p6.json");
    j["encoder"] = load_json_file(kSrc + "/fixtures/encoders/ideal.json");
    auto field = [&](const json& seed) -> std::string {
        json s = j;
        s["seed"] = seed;
        try {
            scenario_from_json(s, "");
        } catch (const ConfigError& e) {
            return e.field();
        }
        return "<no error>";
    };
    constexpr std::uint64_t k2p53 = 1ULL << 53;
    CHECK(field(k2p53) == "<no error>");
    json top = j;
    top["seed"] = k2p53;
    CHECK(scenario_from_json(top, "").seed == k2p53);
    // 2^53 + 1 rounds to 2^53 as a double: the bound is compared as an integer.
    CHECK(field(k2p53 + 1) == "seed");
    CHECK(field(std::numeric_limits<std::uint64_t>::max()) == "seed");
    CHECK(field(std::numeric_limits<std::int64_t>::max()) == "seed");
    CHECK(field(-1) == "seed");
    CHECK(field(1.5) == "seed");
    CHECK(field(9007199254740993.0) == "<no error>");  // a float literal: the double is 2^53 exactly
    CHECK(field("7") == "seed");
}

TEST_CASE("Ring: first in, first out across growth and wrap-around", "[config]") {
    // Against a deque: pushes and pops of varying sizes, so the ring wraps and grows many times.
    Ring<double> r;
    std::deque<double> ref;
    double next = 0;
    std::vector<double> in, out;
    for (int step = 0; step < 2000; ++step) {
        const std::size_t push = static_cast<std::size_t>((step * 37) % 1500), pop = static_cast<std::size_t>((step * 53) % 1400);
        in.resize(push);
        for (auto& v : in) v = next++;
        if (step % 5 == 0) {
            r.push_fill(-1.0, push);
            ref.insert(ref.end(), push, -1.0);
        } else {
            r.push(in.data(), push);
            ref.insert(ref.end(), in.begin(), in.end());
        }
        REQUIRE(r.size() == ref.size());
        const std::size_t take = std::min(pop, r.size());
        out.resize(take);
        r.pop(out.data(), take);
        for (std::size_t i = 0; i < take; ++i) {
            REQUIRE(out[i] == ref.front());
            ref.pop_front();
        }
    }
    REQUIRE(r.size() == ref.size());
    r.clear();
    CHECK(r.empty());
}

}  // namespace test_config_cpp
