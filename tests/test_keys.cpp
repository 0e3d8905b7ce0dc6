// The scenario's keys are described once, where they are read (signal_gen/base/key_table.hpp):
// every key the readers take is in their tables, and every key in the tables is taken.
#include "helpers.hpp"

#include "server/engine/scenario.hpp"
#include "server/engine/scenario_keys.hpp"
#include "server/engine/schema_info.hpp"
#include "signal_gen/encoder.hpp"
#include "signal_gen/keys.hpp"
#include "signal_gen/motion.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <fstream>
#include <set>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_keys_cpp {

using namespace fringe;
using nlohmann::json;

namespace {

// A value the key takes: its default, else one inside its range.
json sample(const ParamInfo& p) {
    if (!p.default_value.is_null()) return p.default_value;
    switch (p.type) {
    case ParamType::Boolean: return true;
    case ParamType::Choice: return p.options.at(0);
    case ParamType::String: return "x";
    case ParamType::Integer: return static_cast<long long>(std::isfinite(p.min) ? p.min : 0.0);
    case ParamType::Number: return std::clamp(1.0, p.min, p.max);
    }
    return nullptr;
}

// Sets a dotted key ("noise.sigma_add_v"; "harmonics[].order" in the array's first element).
void set_dotted(json& j, const std::string& dotted, const json& v) {
    json* at = &j;
    std::size_t from = 0;
    for (auto dot = dotted.find('.'); dot != std::string::npos; from = dot + 1, dot = dotted.find('.', from)) {
        std::string part = dotted.substr(from, dot - from);
        if (part.size() > 2 && part.compare(part.size() - 2, 2, "[]") == 0) at = &(*at)[part.substr(0, part.size() - 2)][0];
        else at = &(*at)[part];
    }
    (*at)[dotted.substr(from)] = v;
}

// Every key of a written object as a dotted name (array elements as "[]").
void leaves(const json& j, const std::string& prefix, std::set<std::string>& out) {
    for (auto it = j.begin(); it != j.end(); ++it) {
        const std::string name = prefix.empty() ? it.key() : prefix + "." + it.key();
        if (it->is_object()) leaves(*it, name, out);
        else if (it->is_array() && (it->empty() || (*it)[0].is_object()))
            for (const auto& e : *it) leaves(e, name + "[]", out);
        else out.insert(name);
    }
}

std::set<std::string> described(const KeyTable& t) {
    std::set<std::string> s;
    for (const auto& k : t.keys()) s.insert(k.param.name);
    return s;
}

}  // namespace

TEST_CASE("keys: every encoder key is described where it is read, and every described key is read", "[keys][schema]") {
    const KeyTable& t = encoder_keys();
    // The two models take different keys: optics is the diffraction model's, harmonics the ideal one's.
    for (const std::string model : {"diffraction", "ideal"}) {
        INFO(model);
        json j = json::object();
        for (const auto& k : t.keys()) {
            const std::string& n = k.param.name;
            if ((model == "ideal" && n.rfind("optics.", 0) == 0) || (model == "diffraction" && n.rfind("harmonics", 0) == 0)) continue;
            set_dotted(j, n, n == "model" ? json(model) : sample(k.param));
        }
        EncoderProfile e;
        REQUIRE_NOTHROW(e = encoder_from_json(j));  // a described key the reader did not take would be "unknown"
        // What a profile is written with is described too (and read back the same).
        std::set<std::string> written;
        leaves(json(e), "", written);
        for (const auto& w : written) {
            INFO(w);
            CHECK(described(t).count(w) == 1);
        }
        CHECK(json(encoder_from_json(json(e))) == json(e));
    }
    // A key the table does not describe cannot be read (a reader asking for one is a bug).
    CHECK_THROWS_AS(t["noise.sigma_add"], std::logic_error);
    CHECK_THROWS_WITH(encoder_from_json(json{{"noise", {{"sigma_add", 1e-3}}}}), Catch::Contains("encoder.noise.sigma_add") && Catch::Contains("unknown"));
}

TEST_CASE("keys: every motion kind's keys are described where they are read", "[keys][schema]") {
    test::TempDir dir("fringe-keys");
    std::ofstream(dir.path / "table.csv") << "t_s,phi_rad\n0,0\n1,0.5\n";
    std::set<std::string> kinds;
    for (const auto& kind : motion_kinds()) {
        kinds.insert(kind.kind);
        // constant: velocity_rad_s or electrical_freq_hz, not both
        for (const std::string leave_out : {"electrical_freq_hz", "velocity_rad_s"}) {
            if (kind.kind != "constant" && leave_out == "velocity_rad_s") continue;
            INFO(kind.kind << " without " << leave_out);
            json j{{"kind", kind.kind}};
            for (const auto& k : kind.keys.keys())
                if (k.param.name != leave_out) j[k.param.name] = k.param.name == "file" ? json("table.csv") : sample(k.param);
            MotionProfile m;
            REQUIRE_NOTHROW(m = motion_from_json(j, dir.path.string(), 1024, "motion"));
            json written = m;
            for (auto it = written.begin(); it != written.end(); ++it) {
                INFO(it.key());
                CHECK((it.key() == "kind" || described(kind.keys).count(it.key()) == 1));
            }
        }
    }
    CHECK(kinds == std::set<std::string>{"constant", "ramp", "trapezoid", "sine", "steps", "table"});
    CHECK_THROWS_WITH(motion_from_json(json{{"kind", "ramp"}, {"accel_rad_s2", 1.0}, {"freq_hz", 2.0}}, "", 1024, "motion"),
                      Catch::Contains("motion.freq_hz") && Catch::Contains("unknown key for a ramp motion"));
}

TEST_CASE("keys: the scenario's and a limit's own keys are described where they are read", "[keys][schema]") {
    json j{{"encoder", {{"model", "ideal"}}}, {"motion", {{"kind", "constant"}, {"velocity_rad_s", 1.0}}}, {"estimators", json::array({json{{"name", "atan2"}}})}};
    for (const auto& k : scenario_keys().keys()) set_dotted(j, k.param.name, sample(k.param));
    json limit = json::object();
    for (const auto& k : limit_keys().keys()) limit[k.param.name] = k.param.name == "metric" ? json("rms_rad") : sample(k.param);
    j["limits"] = json::array({limit});
    Scenario sc;
    REQUIRE_NOTHROW(sc = scenario_from_json(j, ""));
    CHECK(sc.limits.size() == 1);
    // GET /api/v1/schema is these tables.
    const json schema = scenario_schema();
    CHECK(schema["scenario"] == json(scenario_keys().keys()));
    CHECK(schema["limit"] == json(limit_keys().keys()));
    CHECK(schema["encoder"] == json(encoder_keys().keys()));
    REQUIRE(schema["motion"].size() == motion_kinds().size());
    for (std::size_t i = 0; i < motion_kinds().size(); ++i) CHECK(schema["motion"][i]["params"] == json(motion_kinds()[i].keys.keys()));
}

}  // namespace test_keys_cpp
