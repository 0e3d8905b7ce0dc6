// Scenario: what to synthesise (encoder + motion + sampling + seed + duration). Later
// issues extend it with converter, device, estimators and limits. Strict JSON: unknown keys
// and out-of-range values are errors naming the key.
#pragma once

#include "signal_gen/encoder.hpp"
#include "signal_gen/motion.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>

namespace fringe {

struct Scenario {
    std::string name = "unnamed";
    std::string description;
    EncoderProfile encoder;
    MotionProfile motion;
    double sample_rate_hz = 100000.0;
    double duration_s = 1.0;
    double t0_s = 0.0;
    std::uint64_t seed = 1;

    std::uint64_t samples() const;
};

// base_dir resolves relative paths (an "encoder" given as a file name, a motion table).
Scenario scenario_from_json(const nlohmann::json& j, const std::string& base_dir);
Scenario load_scenario(const std::string& path);
EncoderProfile load_encoder(const std::string& path);
nlohmann::json load_json_file(const std::string& path);  // throws ConfigError with the parse position
void to_json(nlohmann::json& j, const Scenario& s);  // as run: the encoder inlined

}  // namespace fringe
