#include "signal_gen/base/params.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace fringe {

using nlohmann::json;

namespace {
const char* type_name(ParamType t) {
    switch (t) {
        case ParamType::Number: return "number";
        case ParamType::Integer: return "integer";
        case ParamType::Boolean: return "boolean";
        case ParamType::Choice: return "choice";
        case ParamType::String: return "string";
    }
    return "?";
}

std::string range_text(const ParamInfo& p) {
    std::ostringstream os;
    os << "[" << p.min << ", " << p.max << "]";
    return os.str();
}
}  // namespace

void to_json(json& j, const ParamInfo& p) {
    j = json{{"name", p.name}, {"unit", p.unit}, {"type", type_name(p.type)},
             {"default", p.default_value}, {"description", p.description}};
    if (p.type == ParamType::Number || p.type == ParamType::Integer) {
        if (std::isfinite(p.min)) j["min"] = p.min;
        if (std::isfinite(p.max)) j["max"] = p.max;
    }
    if (p.type == ParamType::Choice) j["options"] = p.options;
}


double Params::number(const std::string& key) const {
    const auto& v = v_.at(key);
    if (v.is_null()) throw ConfigError("params." + key, "has no value and no default");
    return v.get<double>();
}
std::optional<double> Params::optional_number(const std::string& key) const {
    const auto& v = v_.at(key);
    if (v.is_null()) return std::nullopt;
    return v.get<double>();
}
long long Params::integer(const std::string& key) const { return v_.at(key).get<long long>(); }
bool Params::boolean(const std::string& key) const { return v_.at(key).get<bool>(); }
std::string Params::string(const std::string& key) const {
    const auto& v = v_.at(key);
    return v.is_null() ? std::string() : v.get<std::string>();
}

Params resolve_params(const std::vector<ParamInfo>& infos, const json& given, const std::string& path) {
    if (!given.is_null() && !given.is_object()) throw ConfigError(path, "must be an object");
    json out = json::object();
    for (const auto& p : infos) out[p.name] = p.default_value;
    if (given.is_null()) return Params(out);
    for (const auto& [key, value] : given.items()) {
        const std::string field = path + "." + key;
        const ParamInfo* info = nullptr;
        for (const auto& p : infos)
            if (p.name == key) info = &p;
        if (!info) {
            std::string known;
            for (const auto& p : infos) known += (known.empty() ? "" : ", ") + p.name;
            throw ConfigError(field, "unknown parameter (known: " + known + ")");
        }
        if (value.is_null()) { out[key] = info->default_value; continue; }
        switch (info->type) {
            case ParamType::Number:
            case ParamType::Integer: {
                const bool integer = info->type == ParamType::Integer;
                if (!value.is_number()) throw ConfigError(field, integer ? "must be an integer" : "must be a number");
                const double d = value.get<double>();
                if (!std::isfinite(d)) throw ConfigError(field, "must be finite");
                // 8.0 is the integer 8 (JSON writers and people write it so); 8.5 is not
                if (integer && !value.is_number_integer() && d != std::floor(d)) throw ConfigError(field, "must be an integer");
                if (d < info->min || d > info->max)
                    throw ConfigError(field, "out of range " + range_text(*info) + (info->unit.empty() ? "" : " " + info->unit));
                if (integer && !value.is_number_integer())
                    out[key] = static_cast<long long>(d);
                else
                    out[key] = value;
                break;
            }
            case ParamType::Boolean:
                if (!value.is_boolean()) throw ConfigError(field, "must be true or false");
                out[key] = value;
                break;
            case ParamType::Choice: {
                if (!value.is_string()) throw ConfigError(field, "must be a string");
                const auto s = value.get<std::string>();
                bool ok = false;
                for (const auto& o : info->options) ok |= (o == s);
                if (!ok) {
                    std::string opts;
                    for (const auto& o : info->options) opts += (opts.empty() ? "" : ", ") + o;
                    throw ConfigError(field, "must be one of: " + opts);
                }
                out[key] = value;
                break;
            }
            case ParamType::String:
                if (!value.is_string()) throw ConfigError(field, "must be a string");
                out[key] = value;
                break;
        }
    }
    return Params(out);
}

json parse_param_assignments(const std::vector<ParamInfo>& infos, const std::vector<std::string>& assignments,
                             const std::string& path) {
    json out = json::object();
    for (const auto& a : assignments) {
        const auto eq = a.find('=');
        if (eq == std::string::npos || eq == 0) throw ConfigError(path, "expected key=value, got '" + a + "'");
        const std::string key = a.substr(0, eq), text = a.substr(eq + 1);
        const ParamInfo* info = nullptr;
        for (const auto& p : infos)
            if (p.name == key) info = &p;
        const std::string field = path + "." + key;
        // given twice on one command line: one of them would be dropped without a word
        if (out.contains(key)) throw ConfigError(field, "given twice ('" + key + "=" + out[key].dump() + "' and '" + a + "')");
        if (!info) {
            out[key] = text;  // resolve_params reports it as unknown, with the known names
            continue;
        }
        switch (info->type) {
            case ParamType::Number:
            case ParamType::Integer: {
                std::size_t used = 0;
                double d = 0;
                try {
                    d = std::stod(text, &used);
                } catch (const std::out_of_range&) {
                    // a number, but beyond a double (1e-400 underflows, 1e400 overflows)
                    throw ConfigError(field, "'" + text + "' is beyond the range of a double (about 2.2e-308 to 1.8e308 in magnitude)");
                } catch (const std::exception&) {
                    used = 0;
                }
                // decimal only: strtod also reads hex ("0x10" = 16) and "infinity"
                const bool decimal = text.find_first_not_of("0123456789+-.eE") == std::string::npos;
                if (used != text.size() || text.empty() || !decimal) throw ConfigError(field, "'" + text + "' is not a decimal number");
                if (info->type == ParamType::Integer) {
                    if (d != std::floor(d)) throw ConfigError(field, "'" + text + "' is not an integer");
                    out[key] = static_cast<long long>(d);
                } else {
                    out[key] = d;
                }
                break;
            }
            case ParamType::Boolean:
                if (text == "true" || text == "1") out[key] = true;
                else if (text == "false" || text == "0") out[key] = false;
                else throw ConfigError(field, "'" + text + "' is not true/false");
                break;
            default: out[key] = text;
        }
    }
    return out;
}

}  // namespace fringe
