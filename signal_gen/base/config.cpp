#include "signal_gen/base/config.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <sstream>

namespace fringe {

using nlohmann::json;

namespace {
std::string type_name(const json& v) { return v.type_name(); }

std::string fmt(double x) {
    std::ostringstream os;
    os << x;
    return os.str();
}
}  // namespace

JsonReader::JsonReader(const json& object, std::string path) : obj_(&object), path_(std::move(path)) {
    if (!object.is_object())
        throw ConfigError(path_, "expected a JSON object, got " + type_name(object));
}

std::string JsonReader::path_of(const std::string& key) const {
    return path_.empty() ? key : path_ + "." + key;
}

bool JsonReader::has(const std::string& key) const {
    asked_.insert(key);
    return obj_->contains(key);
}

bool JsonReader::has_object(const std::string& key) const {
    return obj_->contains(key) && (*obj_)[key].is_object();
}

const json& JsonReader::raw(const std::string& key) {
    auto it = obj_->find(key);
    if (it == obj_->end()) throw ConfigError(path_of(key), "required key is missing");
    used_.insert(key);
    return *it;
}

double JsonReader::number(const std::string& key, double lo, double hi) {
    const json& v = raw(key);
    if (!v.is_number())
        throw ConfigError(path_of(key), "expected a number, got " + type_name(v));
    double x = v.get<double>();
    if (!std::isfinite(x)) throw ConfigError(path_of(key), "must be finite");
    if (x < lo || x > hi)
        throw ConfigError(path_of(key), "value " + fmt(x) + " out of range [" + fmt(lo) + ", " + fmt(hi) + "]");
    return x;
}

double JsonReader::number(const std::string& key, double def, double lo, double hi) {
    if (!has(key)) return def;
    return number(key, lo, hi);
}

std::optional<double> JsonReader::optional_number(const std::string& key, double lo, double hi) {
    if (!has(key) || (*obj_)[key].is_null()) {
        if (has(key)) used_.insert(key);
        return std::nullopt;
    }
    return number(key, lo, hi);
}

long long JsonReader::integer(const std::string& key, long long lo, long long hi) {
    const json& v = raw(key);
    if (!v.is_number_integer() && !(v.is_number_float() && std::floor(v.get<double>()) == v.get<double>()))
        throw ConfigError(path_of(key), "expected an integer, got " + (v.is_number() ? fmt(v.get<double>()) : type_name(v)));
    auto out_of_range = [&](const std::string& value) {
        return ConfigError(path_of(key), "value " + value + " out of range [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    };
    // Integers are compared as integers: through a double, 2^53 + 1 would round to 2^53 and pass.
    if (v.is_number_unsigned()) {
        const auto u = v.get<std::uint64_t>();
        if (hi < 0 || u > static_cast<std::uint64_t>(hi) || (lo > 0 && u < static_cast<std::uint64_t>(lo))) throw out_of_range(std::to_string(u));
        return static_cast<long long>(u);
    }
    if (v.is_number_integer()) {
        const auto i = v.get<long long>();
        if (i < lo || i > hi) throw out_of_range(std::to_string(i));
        return i;
    }
    const double d = v.get<double>();
    // |d| < 2^63 also keeps the conversion defined when hi is LLONG_MAX (its double is 2^63).
    if (!(d >= static_cast<double>(lo) && d <= static_cast<double>(hi)) || std::fabs(d) >= 0x1p63) throw out_of_range(fmt(d));
    return static_cast<long long>(d);
}

long long JsonReader::integer(const std::string& key, long long def, long long lo, long long hi) {
    if (!has(key)) return def;
    return integer(key, lo, hi);
}

bool JsonReader::boolean(const std::string& key, bool def) {
    if (!has(key)) return def;
    const json& v = raw(key);
    if (!v.is_boolean()) throw ConfigError(path_of(key), "expected true or false, got " + type_name(v));
    return v.get<bool>();
}

std::string JsonReader::string(const std::string& key) {
    const json& v = raw(key);
    if (!v.is_string()) throw ConfigError(path_of(key), "expected a string, got " + type_name(v));
    return v.get<std::string>();
}

std::string JsonReader::string(const std::string& key, const std::string& def) {
    if (!has(key)) return def;
    return string(key);
}

std::string JsonReader::choice(const std::string& key, const std::string& def,
                               const std::vector<std::string>& allowed) {
    std::string s = string(key, def);
    for (const auto& a : allowed)
        if (a == s) return s;
    std::string list;
    for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
    throw ConfigError(path_of(key), "'" + s + "' is not one of: " + list);
}

JsonReader JsonReader::object(const std::string& key) {
    const json& v = raw(key);
    return JsonReader(v, path_of(key));
}

namespace {
// Levenshtein distance, for "did you mean" on misspelt keys.
std::size_t edit_distance(const std::string& a, const std::string& b) {
    std::vector<std::size_t> prev(b.size() + 1), cur(b.size() + 1);
    for (std::size_t j = 0; j <= b.size(); ++j) prev[j] = j;
    for (std::size_t i = 1; i <= a.size(); ++i) {
        cur[0] = i;
        for (std::size_t j = 1; j <= b.size(); ++j)
            cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
        std::swap(prev, cur);
    }
    return prev[b.size()];
}
}  // namespace

void JsonReader::finish() const {
    for (auto it = obj_->begin(); it != obj_->end(); ++it) {
        if (used_.count(it.key())) continue;
        std::string best;
        std::size_t best_d = std::max<std::size_t>(2, it.key().size() / 3) + 1;
        for (const auto& k : asked_) {
            if (used_.count(k)) continue;  // given already
            const std::size_t d = edit_distance(it.key(), k);
            if (d < best_d) { best_d = d; best = k; }
        }
        throw ConfigError(path_of(it.key()), best.empty() ? "unknown key" : "unknown key (did you mean '" + best + "'?)");
    }
}

}  // namespace fringe
