// What the parts of the HTTP service share (service.cpp: routing and runs; service_auth.cpp:
// token, Host check, device and file sandbox; service_captures.cpp: the capture store;
// service_report_cache.cpp: rendered reports): request parsing, JSON answers and errors,
// path and host checks. Internal to server/service*.cpp.
#pragma once

#include "server/http/service.hpp"

#include "signal_gen/base/config.hpp"
#include "signal_gen/base/json_bounded.hpp"
#include "signal_gen/base/text.hpp"

#include <nlohmann/json.hpp>

#include <arpa/inet.h>
#include <fnmatch.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace fringe::service_detail {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr std::size_t kReportCache = 64;
constexpr std::uint64_t kMaxSeed = 1ull << 53;  // the scenario schema's cap (exact in a double)

// An answer decided deep in a handler (bad_encoding, device_not_allowed): handle() turns it
// into the JSON error.
struct HttpError : std::runtime_error {
    int status;
    std::string code, field;
    HttpError(int s, std::string c, const std::string& message, std::string f = "")
        : std::runtime_error(message), status(s), code(std::move(c)), field(std::move(f)) {}
};

// Strings from outside may hold bytes that are not UTF-8: they become U+FFFD instead of
// making dump() throw.
inline std::string dump_safe(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

inline void require_utf8(const std::string& s, const std::string& field, const std::string& what) {
    if (const auto at = invalid_utf8_at(s); at != std::string::npos)
        throw HttpError(400, "bad_encoding", what + " is not valid UTF-8 (byte " + std::to_string(at) + ")", field);
}

inline bool valid_id(const std::string& id) {
    if (id.empty() || id.size() > 64) return false;
    return std::all_of(id.begin(), id.end(), [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_'; });
}

inline std::string pct_decode(const std::string& s) {
    std::string out;
    for (std::size_t i = 0; i < s.size(); ++i) {
        if (s[i] == '+') out += ' ';
        else if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(static_cast<unsigned char>(s[i + 1])) &&
                 std::isxdigit(static_cast<unsigned char>(s[i + 2]))) {
            out += static_cast<char>(std::stoi(s.substr(i + 1, 2), nullptr, 16));
            i += 2;
        } else out += s[i];
    }
    return out;
}

inline void split_target(const std::string& target, std::string& path, std::map<std::string, std::string>& query) {
    const auto q = target.find('?');
    path = target.substr(0, q);
    if (q == std::string::npos) return;
    const std::string qs = target.substr(q + 1);
    std::size_t pos = 0;
    while (pos <= qs.size()) {
        auto amp = qs.find('&', pos);
        if (amp == std::string::npos) amp = qs.size();
        const std::string kv = qs.substr(pos, amp - pos);
        if (!kv.empty()) {
            const auto eq = kv.find('=');
            std::string k = pct_decode(kv.substr(0, eq));
            // ?limit=1&limit=1000 is ambiguous (one reader takes the first, another the last)
            if (query.count(k)) throw ConfigError(k, "query parameter given more than once");
            query[std::move(k)] = eq == std::string::npos ? "" : pct_decode(kv.substr(eq + 1));
        }
        pos = amp + 1;
    }
}

inline std::vector<std::string> segments(const std::string& path) {
    std::vector<std::string> out;
    std::size_t pos = 1;
    while (pos <= path.size()) {
        auto slash = path.find('/', pos);
        if (slash == std::string::npos) slash = path.size();
        out.push_back(path.substr(pos, slash - pos));
        pos = slash + 1;
    }
    return out;
}

inline HttpResponse json_ok(const json& j, int status = 200) {
    HttpResponse r;
    r.status = status;
    r.body = dump_safe(j);
    return r;
}

// A request body: JSON nested at most kMaxJsonDepth deep, no key twice in an object; errors
// name the field ("scenario.duration_s": 1e400 overflows a double).
inline json parse_body(const std::string& body) {
    if (body.empty()) throw ConfigError("", "the request needs a JSON body");
    require_utf8(body, "body", "the request body");
    return parse_json_bounded(body, "");
}

inline void only_keys(const json& j, std::initializer_list<const char*> keys, const std::string& where) {
    if (!j.is_object()) throw ConfigError(where, "expected a JSON object");
    for (const auto& [k, v] : j.items()) {
        bool ok = false;
        for (const char* key : keys) ok |= k == key;
        if (!ok) {
            std::string known;
            for (const char* key : keys) known += (known.empty() ? "" : ", ") + std::string(key);
            throw ConfigError(where.empty() ? k : where + "." + k, "unknown key (known: " + known + ")");
        }
    }
}

inline bool constant_time_equal(const std::string& a, const std::string& b) {
    unsigned char d = a.size() == b.size() ? 0 : 1;
    for (std::size_t i = 0; i < a.size(); ++i) d |= static_cast<unsigned char>(a[i] ^ b[i % (b.empty() ? 1 : b.size())]);
    return d == 0 && !b.empty();
}

inline std::string content_type_for(const std::string& ext) {
    if (ext == ".html") return "text/html; charset=utf-8";
    if (ext == ".js" || ext == ".mjs") return "text/javascript; charset=utf-8";
    if (ext == ".css") return "text/css; charset=utf-8";
    if (ext == ".json") return "application/json";
    if (ext == ".svg") return "image/svg+xml";
    if (ext == ".png") return "image/png";
    return "application/octet-stream";
}

inline std::string read_file(const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    std::ostringstream ss;
    ss << f.rdbuf();
    return ss.str();
}

// A file reference in a client's scenario must resolve inside root (no absolute paths, no
// escaping with ..).
// inline_ok: the key also takes the object itself (an encoder profile, a motion); a correction
// file is only ever a file.
inline void check_ref(const json& j, const fs::path& base, const fs::path& root, const std::string& field, bool inline_ok = true) {
    if (!j.is_string()) return;
    const fs::path p(j.get<std::string>());
    if (p.is_absolute())
        throw ConfigError(field, inline_ok ? "absolute file paths are not accepted over HTTP; name a fixture or give the object inline"
                                           : "absolute file paths are not accepted over HTTP; name a file inside the fixtures folder (relative to the scenario)");
    const fs::path full = (base / p).lexically_normal();
    const auto rel = full.lexically_relative(root);
    if (rel.empty() || *rel.begin() == "..") throw ConfigError(field, "file references must stay inside the fixtures folder");
}

inline std::string lower(std::string s) {
    for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
}

// The name in a Host header ("Bench.Lab:8080" -> "bench.lab", "[::1]:80" -> "[::1]"), or ""
// if it is not a host[:port].
inline std::string host_name(std::string v) {
    while (!v.empty() && (v.back() == ' ' || v.back() == '\t')) v.pop_back();
    while (!v.empty() && (v.front() == ' ' || v.front() == '\t')) v.erase(0, 1);
    std::string name, rest;
    if (!v.empty() && v[0] == '[') {
        const auto close = v.find(']');
        if (close == std::string::npos) return "";
        name = v.substr(0, close + 1);
        rest = v.substr(close + 1);
        in6_addr a6{};
        if (::inet_pton(AF_INET6, name.substr(1, name.size() - 2).c_str(), &a6) != 1) return "";
    } else {
        const auto colon = v.find(':');
        name = v.substr(0, colon);
        rest = colon == std::string::npos ? "" : v.substr(colon);
        if (name.empty() || !std::all_of(name.begin(), name.end(), [](char c) {
                return std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '_';
            }))
            return "";
    }
    // A port is 1 to 5 digits up to 65535 ("host:" and "host:99999" are not a host[:port]).
    if (!rest.empty() && (rest[0] != ':' || rest.size() < 2 || rest.size() > 6 ||
                          !std::all_of(rest.begin() + 1, rest.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); }) ||
                          std::stoul(rest.substr(1)) > 65535))
        return "";
    name = lower(name);
    if (name.size() > 1 && name.back() == '.') name.pop_back();  // "localhost." is localhost
    return name;
}

inline bool ip_literal(const std::string& name) {
    in_addr a4{};
    return ::inet_pton(AF_INET, name.c_str(), &a4) == 1 || (name.size() > 2 && name.front() == '[');  // host_name checked the [v6]
}

// Glob as in a shell: * and ? do not cross '/', nor match a leading '.' of a path part.
inline bool glob_match(const std::string& pattern, const std::string& text) {
    return ::fnmatch(pattern.c_str(), text.c_str(), FNM_PATHNAME | FNM_PERIOD) == 0;
}

}  // namespace fringe::service_detail
