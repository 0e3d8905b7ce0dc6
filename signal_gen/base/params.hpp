// Self-described parameters: estimators and devices describe their settings
// (name, unit, type, default, range) once; the CLI help, the HTTP API and the web forms are
// built from that description, and resolve_params validates user input against it.
#pragma once

#include "signal_gen/base/config.hpp"

#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

namespace fringe {

enum class ParamType { Number, Integer, Boolean, Choice, String };

// Self-description of one parameter. A null default means "derived" (usually from the
// encoder profile); `description` says from what.
struct ParamInfo {
    std::string name;
    std::string unit;  // "" for dimensionless
    ParamType type = ParamType::Number;
    nlohmann::json default_value;
    double min = -kInf, max = kInf;    // Number / Integer
    std::vector<std::string> options;  // Choice
    std::string description;
};
void to_json(nlohmann::json& j, const ParamInfo& p);

// Resolved parameter values: every declared parameter is present (null when derived and
// not given). Built by resolve_params, which rejects unknown keys, wrong types and values
// out of range with a ConfigError naming "params.<key>".
class Params {
public:
    Params() = default;
    explicit Params(nlohmann::json values) : v_(std::move(values)) {}
    double number(const std::string& key) const;
    std::optional<double> optional_number(const std::string& key) const;
    long long integer(const std::string& key) const;
    bool boolean(const std::string& key) const;
    std::string string(const std::string& key) const;
    const nlohmann::json& json() const { return v_; }

private:
    nlohmann::json v_ = nlohmann::json::object();
};

Params resolve_params(const std::vector<ParamInfo>& infos, const nlohmann::json& given,
                      const std::string& path = "params");

// "k=v" strings (CLI --param) to a JSON object, converting each value by its declared type.
nlohmann::json parse_param_assignments(const std::vector<ParamInfo>& infos,
                                       const std::vector<std::string>& assignments,
                                       const std::string& path = "params");

}  // namespace fringe
