// One JSON reader for everything fringe parses from outside (HTTP bodies, scenario, encoder
// and board files, capture headers and sidecars, stored reports, a remote service's answers):
// nesting is bounded (kMaxJsonDepth), an object may not name a key twice, and an error names
// the path of the value it is about ("scenario.estimators[0].params").
//
// Why a depth bound: nlohmann's parser is iterative, but copying, comparing and dumping a
// value recurse once per level, so a 300 KB body of 150 000 '[' overflowed a thread's stack
// in the first copy. A value that never gets deeper than the bound can never do that.
#pragma once

#include "signal_gen/base/config.hpp"

#include <nlohmann/json.hpp>

#include <cstddef>
#include <set>
#include <string>
#include <string_view>
#include <vector>

namespace fringe {

// Arrays and objects nested inside each other, counting the outermost as 1 ({"a":[1]} is 2).
constexpr std::size_t kMaxJsonDepth = 64;
// What fringe wrote itself from values that passed kMaxJsonDepth (a report wraps a scenario a
// few levels deeper than a request did) is read back with this bound.
constexpr std::size_t kMaxStoredJsonDepth = 2 * kMaxJsonDepth;

// nlohmann's DOM parser behind a SAX front that keeps the path of the value being read, stops
// at max_depth and at a repeated key.
class BoundedJsonSax {
public:
    BoundedJsonSax(nlohmann::json& root, std::size_t max_depth) : dom_(root, false), max_depth_(max_depth) {}
    using json = nlohmann::json;
    bool null() { return value() && dom_.null(); }
    bool boolean(bool v) { return value() && dom_.boolean(v); }
    bool number_integer(json::number_integer_t v) { return value() && dom_.number_integer(v); }
    bool number_unsigned(json::number_unsigned_t v) { return value() && dom_.number_unsigned(v); }
    bool number_float(json::number_float_t v, const json::string_t& s) { return value() && dom_.number_float(v, s); }
    bool string(json::string_t& v) { return value() && dom_.string(v); }
    bool binary(json::binary_t& v) { return value() && dom_.binary(v); }
    bool start_object(std::size_t n) {
        value();
        if (frames_.size() >= max_depth_) return too_deep();
        frames_.push_back({false, 0, {}, {}});
        return dom_.start_object(n);
    }
    bool key(json::string_t& k) {
        auto& f = frames_.back();
        f.key = k;
        if (!f.keys.insert(k).second) {
            kind = Kind::duplicate_key;
            error_field = path();
            error = "duplicate key '" + shorten(k, 80) + "' (each key may appear once in an object)";
            return false;
        }
        return dom_.key(k);
    }
    bool end_object() {
        frames_.pop_back();
        return dom_.end_object();
    }
    bool start_array(std::size_t n) {
        value();
        if (frames_.size() >= max_depth_) return too_deep();
        frames_.push_back({true, 0, {}, {}});
        return dom_.start_array(n);
    }
    bool end_array() {
        frames_.pop_back();
        return dom_.end_array();
    }
    bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception& e) {
        kind = e.id == 406 ? Kind::out_of_range : Kind::malformed;
        error_field = path();
        error = shorten(e.what(), 400);
        return false;
    }

    enum class Kind { none, malformed, out_of_range, too_deep, duplicate_key };
    Kind kind = Kind::none;
    std::string error, error_field;

    // What a client sent comes back bounded: a megabyte key or string must not come back whole.
    static std::string shorten(std::string s, std::size_t max) {
        if (s.size() <= max) return s;
        std::size_t head = max / 2, tail = max / 2;
        while (head > 0 && (static_cast<unsigned char>(s[head]) & 0xC0) == 0x80) --head;  // whole UTF-8 characters
        while (tail > 0 && (static_cast<unsigned char>(s[s.size() - tail]) & 0xC0) == 0x80) --tail;
        return s.substr(0, head) + "..." + s.substr(s.size() - tail);
    }

private:
    bool too_deep() {
        kind = Kind::too_deep;
        error_field = path(true);
        error = "nested deeper than " + std::to_string(max_depth_) + " levels of arrays and objects (the limit)";
        return false;
    }
    // The innermost array has counted the value being read (counted) or is about to.
    std::string path(bool counted = false) const {
        std::string out;
        for (std::size_t i = 0; i < frames_.size(); ++i) {
            const auto& f = frames_[i];
            // The innermost array is reading its next element; outer ones, their last.
            if (f.array) {
                out.append(1, '[').append(std::to_string(i + 1 == frames_.size() && !counted ? f.count : f.count - 1)).append(1, ']');
            } else if (!f.key.empty()) {
                if (!out.empty()) out.append(1, '.');
                out.append(f.key);
            }
        }
        return shorten(std::move(out), 240);
    }
    bool value() {
        if (!frames_.empty() && frames_.back().array) ++frames_.back().count;
        return true;
    }
    struct Frame {
        bool array;
        std::size_t count;
        std::string key;
        std::set<std::string> keys;  // an object's keys so far
    };
    nlohmann::detail::json_sax_dom_parser<json> dom_;
    std::size_t max_depth_;
    std::vector<Frame> frames_;
};

// Parses text (any bytes: invalid UTF-8 in a string is malformed JSON). Throws ConfigError
// whose field is the path inside the text and whose message says what is wrong, followed by
// " (in WHAT)" when what is given (a file name): malformed JSON, a number beyond a double,
// nesting deeper than max_depth, a repeated key.
inline nlohmann::json parse_json_bounded(std::string_view text, const std::string& what, std::size_t max_depth = kMaxJsonDepth) {
    nlohmann::json j;
    BoundedJsonSax sax(j, max_depth);
    if (nlohmann::json::sax_parse(text, &sax)) return j;
    const std::string in = what.empty() ? std::string() : " (in " + what + ")";
    switch (sax.kind) {
        case BoundedJsonSax::Kind::out_of_range: {
            // out_of_range.406: a number that does not fit a double (1e400)
            const auto q = sax.error.find('\'');
            throw ConfigError(sax.error_field, "number out of range" + (q == std::string::npos ? std::string() : " (" + sax.error.substr(q) + ")") +
                                                   ": JSON numbers here must fit a double" + in);
        }
        case BoundedJsonSax::Kind::too_deep:
        case BoundedJsonSax::Kind::duplicate_key: throw ConfigError(sax.error_field, sax.error + in);
        default: throw ConfigError(sax.error_field, "malformed JSON: " + sax.error + in);
    }
}

}  // namespace fringe
