// Strict JSON configuration reading: every key is consumed or rejected.
//
// Config structs serialize in one place (docs/schema.md lists the keys); unknown keys, wrong types and
// out-of-range values are errors that name the key (as a dotted path, e.g.
// "encoder.noise.sigma_add_v").
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <limits>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace fringe {

// A configuration value is missing, unknown, of the wrong type or out of range.
class ConfigError : public std::runtime_error {
public:
    ConfigError(std::string field, const std::string& message)
        : std::runtime_error(field.empty() ? message : field + ": " + message),
          field_(std::move(field)), message_(message) {}
    const std::string& field() const { return field_; }
    const std::string& message() const { return message_; }
    // The same error one level down, e.g. "params.x" -> "estimators[1].params.x".
    ConfigError prefixed(const std::string& prefix) const {
        return ConfigError(field_.empty() ? prefix : prefix + "." + field_, message_);
    }

private:
    std::string field_;
    std::string message_;
};

// Reads one JSON object under a dotted path. Call finish() when done: any key that was
// not read is reported as unknown.
class JsonReader {
public:
    JsonReader(const nlohmann::json& object, std::string path);
    ~JsonReader() = default;
    JsonReader(const JsonReader&) = delete;
    JsonReader& operator=(const JsonReader&) = delete;

    bool has(const std::string& key) const;
    const nlohmann::json& raw(const std::string& key);  // marks read; throws if absent

    double number(const std::string& key, double lo, double hi);  // required
    double number(const std::string& key, double def, double lo, double hi);
    std::optional<double> optional_number(const std::string& key, double lo, double hi);
    long long integer(const std::string& key, long long def, long long lo, long long hi);
    long long integer(const std::string& key, long long lo, long long hi);  // required
    bool boolean(const std::string& key, bool def);
    std::string string(const std::string& key);  // required
    std::string string(const std::string& key, const std::string& def);
    std::string choice(const std::string& key, const std::string& def,
                       const std::vector<std::string>& allowed);

    // A nested object: returns a reader for it (caller must finish() it).
    JsonReader object(const std::string& key);
    bool has_object(const std::string& key) const;

    std::string path_of(const std::string& key) const;
    const std::string& path() const { return path_; }

    // Throws ConfigError naming the first key that was never read.
    void finish() const;

    JsonReader(JsonReader&&) = default;

private:
    const nlohmann::json* obj_;
    std::string path_;
    std::set<std::string> used_;
    mutable std::set<std::string> asked_;  // every key looked for: the candidates for 'did you mean'
};

constexpr double kInf = std::numeric_limits<double>::infinity();

}  // namespace fringe
