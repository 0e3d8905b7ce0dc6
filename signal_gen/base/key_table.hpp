// The keys of a configuration object described as data where they are read: a reader takes
// each key's range and default from its table by name, so every key it reads is described
// (asking for an undescribed one is a programming error, std::logic_error), and the table is
// what describes the keys to others (GET /api/v1/schema and the scenario editor built from
// it; a test parses every described key). The same ParamInfo that estimators and drivers
// describe their parameters with (params.hpp).
#pragma once

#include "signal_gen/base/config.hpp"
#include "signal_gen/base/params.hpp"

#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace fringe {

// One key, named by its dotted path inside the object read ("noise.sigma_add_v";
// "harmonics[].order" for a key of each element of an array). editor: the scenario editor
// offers it as a field (the others are kept as the scenario gives them: model-specific,
// structured or rarely set). A range that depends on another key is left open here, checked
// by the reader and said in the description.
struct KeyInfo {
    ParamInfo param;
    bool editor = true;
};
void to_json(nlohmann::json& j, const KeyInfo& k);  // the ParamInfo, plus "editor": false when not offered

class KeyTable {
public:
    explicit KeyTable(std::vector<KeyInfo> keys) : keys_(std::move(keys)) {}
    const std::vector<KeyInfo>& keys() const { return keys_; }
    // The key's description; throws std::logic_error when the table has none.
    const ParamInfo& operator[](std::string_view dotted) const;

    // Reads the key (the last part of its dotted name) from r, the reader of the object that
    // holds it, with the table's range; a null default makes it required. def/lo/hi: a default
    // or a range that depends on other keys (described in words).
    double number(JsonReader& r, std::string_view dotted) const;
    double number(JsonReader& r, std::string_view dotted, double def) const;
    double number_in(JsonReader& r, std::string_view dotted, double def, double lo, double hi) const;
    std::optional<double> optional_number(JsonReader& r, std::string_view dotted) const;
    long long integer(JsonReader& r, std::string_view dotted) const;
    bool boolean(JsonReader& r, std::string_view dotted) const;
    std::string string(JsonReader& r, std::string_view dotted) const;  // required when the default is null
    std::string choice(JsonReader& r, std::string_view dotted) const;
    // The leaf key a reader of its object reads ("noise.sigma_add_v" -> "sigma_add_v").
    static std::string leaf(std::string_view dotted);

private:
    std::vector<KeyInfo> keys_;
};

// Builders for the tables.
KeyInfo key_number(std::string name, std::string unit, nlohmann::json def, double lo, double hi, std::string description, bool editor = true);
KeyInfo key_integer(std::string name, std::string unit, nlohmann::json def, double lo, double hi, std::string description, bool editor = true);
KeyInfo key_boolean(std::string name, bool def, std::string description, bool editor = true);
KeyInfo key_string(std::string name, nlohmann::json def, std::string description, bool editor = true);
KeyInfo key_choice(std::string name, std::string def, std::vector<std::string> options, std::string description, bool editor = true);

}  // namespace fringe
