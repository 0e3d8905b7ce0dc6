#include "signal_gen/base/key_table.hpp"

#include <stdexcept>

namespace fringe {

using nlohmann::json;

void to_json(json& j, const KeyInfo& k) {
    to_json(j, k.param);
    if (!k.editor) j["editor"] = false;
}

const ParamInfo& KeyTable::operator[](std::string_view dotted) const {
    for (const auto& k : keys_)
        if (k.param.name == dotted) return k.param;
    throw std::logic_error("the key '" + std::string(dotted) + "' is read but not described in its table");
}

std::string KeyTable::leaf(std::string_view dotted) {
    const auto dot = dotted.rfind('.');
    return std::string(dot == std::string_view::npos ? dotted : dotted.substr(dot + 1));
}

double KeyTable::number(JsonReader& r, std::string_view dotted) const {
    const ParamInfo& p = (*this)[dotted];
    if (p.default_value.is_null()) return r.number(leaf(dotted), p.min, p.max);
    return r.number(leaf(dotted), p.default_value.get<double>(), p.min, p.max);
}

double KeyTable::number(JsonReader& r, std::string_view dotted, double def) const {
    const ParamInfo& p = (*this)[dotted];
    return r.number(leaf(dotted), def, p.min, p.max);
}

double KeyTable::number_in(JsonReader& r, std::string_view dotted, double def, double lo, double hi) const {
    (void)(*this)[dotted];
    return r.number(leaf(dotted), def, lo, hi);
}

std::optional<double> KeyTable::optional_number(JsonReader& r, std::string_view dotted) const {
    const ParamInfo& p = (*this)[dotted];
    return r.optional_number(leaf(dotted), p.min, p.max);
}

long long KeyTable::integer(JsonReader& r, std::string_view dotted) const {
    const ParamInfo& p = (*this)[dotted];
    const auto lo = static_cast<long long>(p.min), hi = static_cast<long long>(p.max);
    if (p.default_value.is_null()) return r.integer(leaf(dotted), lo, hi);
    return r.integer(leaf(dotted), p.default_value.get<long long>(), lo, hi);
}

bool KeyTable::boolean(JsonReader& r, std::string_view dotted) const {
    const ParamInfo& p = (*this)[dotted];
    return r.boolean(leaf(dotted), p.default_value.get<bool>());
}

std::string KeyTable::string(JsonReader& r, std::string_view dotted) const {
    const ParamInfo& p = (*this)[dotted];
    if (p.default_value.is_null()) return r.string(leaf(dotted));
    return r.string(leaf(dotted), p.default_value.get<std::string>());
}

std::string KeyTable::choice(JsonReader& r, std::string_view dotted) const {
    const ParamInfo& p = (*this)[dotted];
    return r.choice(leaf(dotted), p.default_value.get<std::string>(), p.options);
}

namespace {
KeyInfo make(std::string name, std::string unit, ParamType type, json def, std::string description, bool editor) {
    KeyInfo k;
    k.param.name = std::move(name);
    k.param.unit = std::move(unit);
    k.param.type = type;
    k.param.default_value = std::move(def);
    k.param.description = std::move(description);
    k.editor = editor;
    return k;
}
}  // namespace

KeyInfo key_number(std::string name, std::string unit, json def, double lo, double hi, std::string description, bool editor) {
    KeyInfo k = make(std::move(name), std::move(unit), ParamType::Number, std::move(def), std::move(description), editor);
    k.param.min = lo;
    k.param.max = hi;
    return k;
}
KeyInfo key_integer(std::string name, std::string unit, json def, double lo, double hi, std::string description, bool editor) {
    KeyInfo k = key_number(std::move(name), std::move(unit), std::move(def), lo, hi, std::move(description), editor);
    k.param.type = ParamType::Integer;
    return k;
}
KeyInfo key_boolean(std::string name, bool def, std::string description, bool editor) {
    return make(std::move(name), "", ParamType::Boolean, def, std::move(description), editor);
}
KeyInfo key_string(std::string name, json def, std::string description, bool editor) {
    return make(std::move(name), "", ParamType::String, std::move(def), std::move(description), editor);
}
KeyInfo key_choice(std::string name, std::string def, std::vector<std::string> options, std::string description, bool editor) {
    KeyInfo k = make(std::move(name), "", ParamType::Choice, std::move(def), std::move(description), editor);
    k.param.options = std::move(options);
    return k;
}

}  // namespace fringe
