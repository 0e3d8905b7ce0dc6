#include "scenario.hpp"

#include "signal_gen/config.hpp"

#include <cmath>
#include <filesystem>
#include <fstream>

namespace fringe {

using nlohmann::json;
namespace fs = std::filesystem;

std::uint64_t Scenario::samples() const {
    return static_cast<std::uint64_t>(std::llround(duration_s * sample_rate_hz));
}

json load_json_file(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw ConfigError("", "cannot open '" + path + "'");
    try {
        return json::parse(in);
    } catch (const json::parse_error& e) {
        throw ConfigError("", path + ": malformed JSON: " + e.what());
    }
}

EncoderProfile load_encoder(const std::string& path) { return encoder_from_json(load_json_file(path), "encoder"); }

Scenario scenario_from_json(const json& j, const std::string& base_dir) {
    JsonReader r(j, "");
    Scenario s;
    s.name = r.string("name", s.name);
    s.description = r.string("description", "");
    const json& enc = r.raw("encoder");
    if (enc.is_string()) {
        fs::path p(enc.get<std::string>());
        if (p.is_relative()) p = fs::path(base_dir) / p;
        try {
            s.encoder = encoder_from_json(load_json_file(p.string()), "encoder");
        } catch (const ConfigError& e) {
            throw ConfigError(e.field().empty() ? "encoder" : e.field(), std::string(e.what()) + " (in " + p.string() + ")");
        }
    } else if (enc.is_object()) {
        s.encoder = encoder_from_json(enc, "encoder");
    } else {
        throw ConfigError("encoder", "expected a profile object or a file name");
    }
    s.sample_rate_hz = r.number("sample_rate_hz", s.sample_rate_hz, 1.0, 1e10);
    s.duration_s = r.number("duration_s", 1e-9, 1e7);
    s.t0_s = r.number("t0_s", 0.0, -1e9, 1e9);
    s.seed = static_cast<std::uint64_t>(r.integer("seed", 1, 0, (1LL << 53)));
    s.motion = motion_from_json(r.raw("motion"), base_dir, s.encoder.lines_per_rev, "motion");
    if (s.samples() < 1) throw ConfigError("duration_s", "gives no samples at this sample rate");
    r.finish();
    return s;
}

Scenario load_scenario(const std::string& path) {
    json j = load_json_file(path);
    return scenario_from_json(j, fs::path(path).parent_path().string());
}

void to_json(json& j, const Scenario& s) {
    j = json{{"name", s.name}, {"encoder", s.encoder}, {"motion", s.motion},
             {"sample_rate_hz", s.sample_rate_hz}, {"duration_s", s.duration_s},
             {"t0_s", s.t0_s}, {"seed", s.seed}};
    if (!s.description.empty()) j["description"] = s.description;
}

}  // namespace fringe
