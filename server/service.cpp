#include "service.hpp"

#include "drivers/capture_file.hpp"
#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "drivers/usb_protocol.hpp"
#include "estimator/estimator.hpp"
#include "evaluate.hpp"
#include "report_formats.hpp"
#include "run.hpp"
#include "scenario.hpp"
#include "signal_gen/config.hpp"
#include "text.hpp"

#include <spdlog/spdlog.h>

#include <arpa/inet.h>
#include <fcntl.h>
#include <fnmatch.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

namespace fringe {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

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
std::string dump_safe(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

void require_utf8(const std::string& s, const std::string& field, const std::string& what) {
    if (const auto at = invalid_utf8_at(s); at != std::string::npos)
        throw HttpError(400, "bad_encoding", what + " is not valid UTF-8 (byte " + std::to_string(at) + ")", field);
}

bool valid_id(const std::string& id) {
    if (id.empty() || id.size() > 64) return false;
    return std::all_of(id.begin(), id.end(), [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_'; });
}

std::string pct_decode(const std::string& s) {
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

void split_target(const std::string& target, std::string& path, std::map<std::string, std::string>& query) {
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
            query[pct_decode(kv.substr(0, eq))] = eq == std::string::npos ? "" : pct_decode(kv.substr(eq + 1));
        }
        pos = amp + 1;
    }
}

std::vector<std::string> segments(const std::string& path) {
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

HttpResponse json_ok(const json& j, int status = 200) {
    HttpResponse r;
    r.status = status;
    r.body = dump_safe(j);
    return r;
}

// nlohmann's DOM parser behind a SAX front that keeps the path of the value being read, so
// a parse error (1e400 overflows a double) names its field: "scenario.duration_s".
class PathSax {
public:
    explicit PathSax(json& root) : dom_(root, false) {}
    bool null() { return value() && dom_.null(); }
    bool boolean(bool v) { return value() && dom_.boolean(v); }
    bool number_integer(json::number_integer_t v) { return value() && dom_.number_integer(v); }
    bool number_unsigned(json::number_unsigned_t v) { return value() && dom_.number_unsigned(v); }
    bool number_float(json::number_float_t v, const json::string_t& s) { return value() && dom_.number_float(v, s); }
    bool string(json::string_t& v) { return value() && dom_.string(v); }
    bool binary(json::binary_t& v) { return value() && dom_.binary(v); }
    bool start_object(std::size_t n) {
        value();
        frames_.push_back({false, 0, {}});
        return dom_.start_object(n);
    }
    bool key(json::string_t& k) {
        frames_.back().key = k;
        return dom_.key(k);
    }
    bool end_object() {
        frames_.pop_back();
        return dom_.end_object();
    }
    bool start_array(std::size_t n) {
        value();
        frames_.push_back({true, 0, {}});
        return dom_.start_array(n);
    }
    bool end_array() {
        frames_.pop_back();
        return dom_.end_array();
    }
    bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception& e) {
        for (std::size_t i = 0; i < frames_.size(); ++i) {
            const auto& f = frames_[i];
            // The innermost array is reading its next element; outer ones, their last.
            if (f.array) {
                error_field.append(1, '[').append(std::to_string(i + 1 == frames_.size() ? f.count : f.count - 1)).append(1, ']');
            } else if (!f.key.empty()) {
                if (!error_field.empty()) error_field.append(1, '.');
                error_field.append(f.key);
            }
        }
        error_id = e.id;
        error = e.what();
        return false;
    }
    std::string error, error_field;
    int error_id = 0;

private:
    bool value() {
        if (!frames_.empty() && frames_.back().array) ++frames_.back().count;
        return true;
    }
    struct Frame {
        bool array;
        std::size_t count;
        std::string key;
    };
    nlohmann::detail::json_sax_dom_parser<json> dom_;
    std::vector<Frame> frames_;
};

json parse_body(const std::string& body) {
    if (body.empty()) throw ConfigError("", "the request needs a JSON body");
    require_utf8(body, "body", "the request body");
    json j;
    PathSax sax(j);
    if (!json::sax_parse(body, &sax)) {
        // out_of_range.406: a number that does not fit a double (1e400)
        if (sax.error_id == 406) {
            const auto q = sax.error.find('\'');
            throw ConfigError(sax.error_field, "number out of range" + (q == std::string::npos ? std::string() : " (" + sax.error.substr(q) + ")") +
                                                   ": JSON numbers here must fit a double");
        }
        throw ConfigError(sax.error_field, "malformed JSON: " + sax.error);
    }
    return j;
}

void only_keys(const json& j, std::initializer_list<const char*> keys, const std::string& where) {
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

bool constant_time_equal(const std::string& a, const std::string& b) {
    unsigned char d = a.size() == b.size() ? 0 : 1;
    for (std::size_t i = 0; i < a.size(); ++i) d |= static_cast<unsigned char>(a[i] ^ b[i % (b.empty() ? 1 : b.size())]);
    return d == 0 && !b.empty();
}

std::string content_type_for(const std::string& ext) {
    if (ext == ".html") return "text/html; charset=utf-8";
    if (ext == ".js" || ext == ".mjs") return "text/javascript; charset=utf-8";
    if (ext == ".css") return "text/css; charset=utf-8";
    if (ext == ".json") return "application/json";
    if (ext == ".svg") return "image/svg+xml";
    if (ext == ".png") return "image/png";
    return "application/octet-stream";
}

std::string read_file(const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    std::ostringstream ss;
    ss << f.rdbuf();
    return ss.str();
}

// A file reference in a client's scenario must resolve inside root (no absolute paths, no
// escaping with ..).
void check_ref(const json& j, const fs::path& base, const fs::path& root, const std::string& field) {
    if (!j.is_string()) return;
    const fs::path p(j.get<std::string>());
    if (p.is_absolute()) throw ConfigError(field, "absolute file paths are not accepted over HTTP; name a fixture or give the object inline");
    const fs::path full = (base / p).lexically_normal();
    const auto rel = full.lexically_relative(root);
    if (rel.empty() || *rel.begin() == "..") throw ConfigError(field, "file references must stay inside the fixtures folder");
}

std::string lower(std::string s) {
    for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
}

// The name in a Host header ("Bench.Lab:8080" -> "bench.lab", "[::1]:80" -> "[::1]"), or ""
// if it is not a host[:port].
std::string host_name(std::string v) {
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
    if (!rest.empty() && (rest[0] != ':' || rest.size() > 6 || !std::all_of(rest.begin() + 1, rest.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); })))
        return "";
    name = lower(name);
    if (name.size() > 1 && name.back() == '.') name.pop_back();  // "localhost." is localhost
    return name;
}

bool ip_literal(const std::string& name) {
    in_addr a4{};
    return ::inet_pton(AF_INET, name.c_str(), &a4) == 1 || (name.size() > 2 && name.front() == '[');  // host_name checked the [v6]
}

// Glob as in a shell: * and ? do not cross '/', nor match a leading '.' of a path part.
bool glob_match(const std::string& pattern, const std::string& text) {
    return ::fnmatch(pattern.c_str(), text.c_str(), FNM_PATHNAME | FNM_PERIOD) == 0;
}

}  // namespace

HttpResponse json_error(int status, const std::string& code, const std::string& message, const std::string& field) {
    json e{{"code", code}, {"message", message}};
    e["field"] = field.empty() ? json(nullptr) : json(field);
    HttpResponse r;
    r.status = status;
    r.body = dump_safe(json{{"error", e}});
    return r;
}

std::string read_token_file(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    if (!f) throw std::runtime_error("cannot read token file " + path);
    std::ostringstream ss;
    ss << f.rdbuf();
    std::string t = ss.str();
    while (!t.empty() && (t.back() == '\n' || t.back() == '\r' || t.back() == ' ')) t.pop_back();
    return t;
}

std::string load_or_create_token(const std::string& path, bool* created) {
    if (created) *created = false;
    if (fs::exists(path)) {
        const std::string t = read_token_file(path);
        if (t.size() < 16) throw std::runtime_error("token file " + path + " holds fewer than 16 characters");
        struct stat st {};
        if (::stat(path.c_str(), &st) == 0 && (st.st_mode & 077))
            spdlog::warn("token file {} is readable by others (mode {:o}); chmod 600 it", path, st.st_mode & 0777);
        return t;
    }
    const auto dir = fs::path(path).parent_path();
    if (!dir.empty()) fs::create_directories(dir);
    std::random_device rd;  // /dev/urandom
    std::string t;
    char hex[9];
    for (int i = 0; i < 8; ++i) {
        std::snprintf(hex, sizeof hex, "%08x", static_cast<unsigned>(rd()));
        t += hex;
    }
    const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL, 0600);
    if (fd < 0) throw std::runtime_error("cannot create token file " + path + ": " + std::strerror(errno));
    const std::string line = t + "\n";
    const bool ok = ::write(fd, line.data(), line.size()) == static_cast<ssize_t>(line.size()) && ::fsync(fd) == 0;
    ::close(fd);
    if (!ok) throw std::runtime_error("cannot write token file " + path);
    if (created) *created = true;
    return t;
}

Service::Service(ServiceConfig cfg) : cfg_(std::move(cfg)) {
    // One service per data folder (throws InstanceLockBusy naming the holder); holding it,
    // every queued or running row of an instance whose lock is free is over for good.
    lock_.acquire_service(cfg_.data_dir, new_instance_id());
    fs::create_directories(fs::path(cfg_.data_dir) / "captures");
    // Clients see our folders by short names: every spelling a message may use (as given,
    // absolute, with symlinks resolved).
    auto name_folder = [&](const std::string& dir, const std::string& name) {
        if (dir.empty()) return;
        std::error_code ec;
        const fs::path abs = fs::absolute(dir, ec).lexically_normal();
        for (fs::path p : {fs::path(dir), abs, fs::weakly_canonical(abs, ec)}) {
            std::string t = p.string();
            while (t.size() > 1 && t.back() == '/') t.pop_back();
            if (t.size() > 1 && t[0] == '/') public_names_.emplace_back(t, name);
        }
    };
    name_folder(cfg_.data_dir, "DATA");
    name_folder(cfg_.fixtures_dir, "fixtures");
    name_folder(dev::boards_dir(), "boards");
    name_folder(cfg_.web_dir, "web");
    std::stable_sort(public_names_.begin(), public_names_.end(), [](const auto& a, const auto& b) { return a.first.size() > b.first.size(); });
    ::chmod((fs::path(cfg_.data_dir) / "captures").c_str(), 0700);
    // --store: DATA/runs.db, sqlite:PATH, or a shared PostgreSQL store fed through DATA/runs.db (forward.hpp).
    store_ = open_store(parse_store_uri(cfg_.store_uri, cfg_.data_dir), lock_.id());
    if (const int n = store_->mark_dead_interrupted(); n > 0) spdlog::warn("{} run(s) of a process that stopped without finishing are marked interrupted", n);
    remove_stale_instance_locks(cfg_.data_dir);
    runs_ = std::make_unique<RunManager>(*store_, store_mu_, cfg_.workers);
    runs_->max_report_bytes = cfg_.max_report_bytes;
    runs_->provenance = cfg_.provenance;
    if (auto* fwd = dynamic_cast<ForwardingStore*>(store_.get())) fwd->start();  // forwards what earlier runs left pending, too
    if (!cfg_.web_dir.empty() && fs::is_directory(cfg_.web_dir)) {
        // The UI is read once: requests look files up by exact name, never build paths.
        for (const auto& e : fs::recursive_directory_iterator(cfg_.web_dir)) {
            if (!e.is_regular_file()) continue;
            const auto rel = fs::relative(e.path(), cfg_.web_dir).generic_string();
            if (rel.rfind("node_modules", 0) == 0 || rel.find("/.") != std::string::npos || rel[0] == '.') continue;
            static_["/" + rel] = {content_type_for(e.path().extension().string()), read_file(e.path())};
        }
        if (!static_.count("/vendor/uPlot.esm.js")) spdlog::warn("web/vendor/uPlot.esm.js is missing (scripts/setup vendors it from npm): plots will not draw");
    }
}

Service::~Service() { shutdown(); }

void Service::set_bound_address(const std::string& host) {
    std::string h = lower(host);
    if (h.find(':') != std::string::npos && h.front() != '[') h = "[" + h + "]";
    cfg_.bind_host = h;
}

std::string Service::public_text(std::string s) const {
    for (const auto& [dir, name] : public_names_) {
        for (std::size_t pos = s.find(dir); pos != std::string::npos; pos = s.find(dir, pos)) {
            const std::size_t end = pos + dir.size();
            // Whole folder names only: /data is not a prefix of /database or /data.old (a
            // sentence's full stop is not part of the name).
            const auto name_char = [&](std::size_t k) {
                return k < s.size() && (std::isalnum(static_cast<unsigned char>(s[k])) || s[k] == '-' || s[k] == '_');
            };
            if (name_char(end) || (end < s.size() && s[end] == '.' && name_char(end + 1)) || (pos > 0 && (name_char(pos - 1) || s[pos - 1] == '.'))) {
                pos = end;
                continue;
            }
            s.replace(pos, dir.size(), name);
            pos += name.size();
        }
    }
    return s;
}

std::optional<HttpResponse> Service::check_host(const HttpRequest& req) const {
    const auto it = req.headers.find("host");
    if (it == req.headers.end()) return std::nullopt;  // HTTP/1.0 (the server refuses HTTP/1.1 without one)
    const std::string name = host_name(it->second);
    if (name.empty()) return json_error(400, "bad_host", "the Host header is not host[:port]", "host");
    bool ok = name == "localhost" || name == "127.0.0.1" || name == "[::1]" || name == cfg_.bind_host;
    // Bound to every interface: any address of this host; a DNS-rebinding page sends a name.
    if (cfg_.bind_host == "0.0.0.0" || cfg_.bind_host == "[::]") ok = ok || ip_literal(name);
    for (const auto& h : cfg_.allow_hosts) ok = ok || name == host_name(h);
    if (ok) return std::nullopt;
    return json_error(421, "misdirected_request",
                      "this service does not answer to the name '" + name +
                          "' (a page that reaches it under another name may be a DNS-rebinding attack); it answers to localhost, 127.0.0.1, [::1], "
                          "its bound address and names the operator adds with fringe serve --allow-host NAME",
                      "host");
}

void Service::shutdown() {
    if (runs_) runs_->shutdown();
}

bool Service::is_upload(const std::string& method, const std::string& target) const {
    return method == "POST" && target.substr(0, target.find('?')) == "/api/v1/captures";
}

bool Service::is_heavy(const std::string& method, const std::string& target) {
    const std::string path = target.substr(0, target.find('?'));
    if (is_upload(method, target)) return true;  // reads the whole capture to check it
    const auto seg = segments(path);
    if (seg.size() == 5 && seg[0] == "api" && seg[1] == "v1") {
        if (seg[2] == "captures" && seg[4] == "evaluate") return method == "POST";
        // The first read of a report parses and renders it (it can be hundreds of MB); later
        // reads come from the cache and stay on the I/O thread.
        if (seg[2] == "runs" && (seg[4] == "report.json" || seg[4] == "report.xml" || seg[4] == "report.html" || seg[4] == "traces")) {
            if (method != "GET") return false;
            std::lock_guard<std::mutex> l(cache_mu_);
            return cache_.count(seg[3]) == 0;
        }
    }
    return false;
}

std::uint64_t Service::upload_room() const {
    std::uint64_t used = 0;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(fs::path(cfg_.data_dir) / "captures", ec)) {
        std::error_code sec;
        if (e.is_regular_file(sec)) used += e.file_size(sec);
    }
    return used >= cfg_.upload_quota_bytes ? 0 : cfg_.upload_quota_bytes - used;
}

std::string Service::new_upload_path() {
    std::lock_guard<std::mutex> l(upload_mu_);
    return (fs::path(cfg_.data_dir) / "captures" / (".upload-" + std::to_string(getpid()) + "-" + std::to_string(++upload_counter_))).string();
}

std::optional<HttpResponse> Service::check_token(const HttpRequest& req, bool state_change) const {
    if (!state_change && !cfg_.token_for_reads) return std::nullopt;
    const auto it = req.headers.find("authorization");
    if (it == req.headers.end() || it->second.empty()) {
        auto r = json_error(401, "unauthorized", state_change ? "this request changes state: send Authorization: Bearer <token> (the token file is printed at start)"
                                                              : "this service is bound beyond loopback: every request needs Authorization: Bearer <token>");
        r.headers.emplace_back("WWW-Authenticate", "Bearer realm=\"fringe\"");
        return r;
    }
    const std::string prefix = "Bearer ";
    if (it->second.compare(0, prefix.size(), prefix) != 0 || !constant_time_equal(it->second.substr(prefix.size()), cfg_.token))
        return json_error(403, "forbidden", "the bearer token is not valid for this service");
    return std::nullopt;
}

std::optional<HttpResponse> Service::precheck(const HttpRequest& head, std::uint64_t content_length, bool has_length) const {
    try {
        // Before anything else: a page under a foreign name learns nothing here.
        if (auto wrong = check_host(head)) return wrong;
        const std::string path = head.target.substr(0, head.target.find('?'));
        if (path.rfind("/api/", 0) != 0) {
            if (head.method != "GET") {
                auto r = json_error(405, "method_not_allowed", "static files are GET only");
                r.headers.emplace_back("Allow", "GET");
                return r;
            }
            return std::nullopt;
        }
        if (head.method != "GET" && head.method != "POST") {
            auto r = json_error(405, "method_not_allowed", "the API uses GET to read and POST to change state");
            r.headers.emplace_back("Allow", "GET, POST");
            return r;
        }
        if (auto denied = check_token(head, head.method == "POST")) return denied;
        const bool upload = is_upload(head.method, head.target);
        const std::uint64_t limit = upload ? cfg_.max_upload_bytes : cfg_.max_body_bytes;
        if (has_length && content_length > limit)
            return json_error(413, "body_too_large", "the body is " + std::to_string(content_length) + " bytes; the limit here is " + std::to_string(limit));
        if (upload && has_length && content_length > 0) {
            if (const auto room = upload_room(); content_length > room)
                return json_error(507, "quota_exceeded", "the upload is " + std::to_string(content_length) + " bytes; uploaded captures may take " +
                                                             std::to_string(cfg_.upload_quota_bytes) + " bytes on disk and " + std::to_string(room) +
                                                             " are left (--upload-quota-mb)");
        }
        return std::nullopt;
    } catch (const std::exception& e) {
        return json_error(500, "internal", public_text(e.what()));
    }
}

HttpResponse Service::handle(const HttpRequest& req) {
    try {
        return handle_request(req);
    } catch (...) {
        // Failed while answering a failure (out of memory): still an answer, never an
        // exception into the server's I/O loop.
        HttpResponse r;
        r.status = 500;
        r.body = R"({"error":{"code":"internal","message":"internal error","field":null}})";
        return r;
    }
}

HttpResponse Service::handle_request(const HttpRequest& req) {
    try {
        std::string path;
        std::map<std::string, std::string> query;
        split_target(req.target, path, query);
        if (auto early = precheck(req, req.body.size(), true)) return *early;
        if (path.find("..") != std::string::npos || path.find('\\') != std::string::npos || path.find('\0') != std::string::npos)
            return json_error(400, "bad_path", "the path may not contain '..' or backslashes");
        require_utf8(path, "path", "the path");
        for (const auto& [k, v] : query) {
            require_utf8(k, "query", "a query parameter's name (percent-decoded)");
            require_utf8(v, k, "the value of query parameter '" + k + "' (percent-decoded)");
        }
        if (!is_upload(req.method, req.target)) require_utf8(req.body, "body", "the request body");  // uploads are binary files
        if (path.rfind("/api/", 0) != 0) return static_file(path);
        return route(req, path, query);
    } catch (const HttpError& e) {
        return json_error(e.status, e.code, public_text(e.what()), e.field);
    } catch (const ConfigError& e) {
        return json_error(400, "invalid", public_text(e.message()), e.field());
    } catch (const CaptureError& e) {
        return json_error(400, "bad_capture", public_text(e.what()));
    } catch (const est::EstimatorError& e) {
        return json_error(400, "estimator_error", public_text(e.what()));
    } catch (const dev::DeviceError& e) {
        return json_error(502, "device_error", public_text(e.what()));
    } catch (const StoreFull& e) {
        spdlog::error("{}", log_escape(e.what()));
        return json_error(507, "storage_full", public_text(std::string("the disk is full: ") + e.what()));
    } catch (const StoreError& e) {
        spdlog::error("{}", log_escape(e.what()));
        return json_error(500, "store_error", public_text(e.what()));
    } catch (const fs::filesystem_error& e) {
        spdlog::error("{} {}: {}", log_escape(req.method), log_escape(req.target), log_escape(e.what()));
        if (e.code() == std::errc::no_space_on_device || e.code() == std::errc::file_too_large)
            return json_error(507, "storage_full", std::string("the disk is full: ") + e.code().message());
        return json_error(500, "internal", public_text(e.what()));
    } catch (const std::exception& e) {
        spdlog::error("{} {}: {}", log_escape(req.method), log_escape(req.target), log_escape(e.what()));
        return json_error(500, "internal", public_text(e.what()));
    }
}

HttpResponse Service::static_file(const std::string& path) const {
    const auto it = static_.find(path == "/" ? "/index.html" : path);
    if (it == static_.end()) return json_error(404, "not_found", "no such file: " + path);
    HttpResponse r;
    r.content_type = it->second.first;
    r.body = it->second.second;
    r.headers.emplace_back("Cache-Control", "no-cache");
    r.headers.emplace_back("Content-Security-Policy",
                           "default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; connect-src 'self'; frame-ancestors 'none'");
    return r;
}

HttpResponse Service::route(const HttpRequest& req, const std::string& path, const std::map<std::string, std::string>& query) {
    const auto seg = segments(path);  // "api", "v1", ...
    if (seg.size() < 3 || seg[1] != "v1") return json_error(404, "not_found", "no such endpoint: " + path + " (the API is under /api/v1)");
    const std::string& top = seg[2];
    const bool get = req.method == "GET", post = req.method == "POST";
    auto wrong_method = [&](const char* allowed) {
        auto r = json_error(405, "method_not_allowed", req.method + " is not allowed on " + path);
        r.headers.emplace_back("Allow", allowed);
        return r;
    };
    auto check_id = [&](const std::string& id) -> std::optional<HttpResponse> {
        if (!valid_id(id)) return json_error(400, "bad_id", "'" + id + "' is not an id (letters, digits, '-', '_'; at most 64)", "id");
        return std::nullopt;
    };

    if (seg.size() == 3) {
        if (top == "health") {
            if (!get) return wrong_method("GET");
            const auto live = runs_->live();
            const auto running = std::count_if(live.begin(), live.end(), [](const RunSnapshot& s) { return s.status == "running"; });
            return json_ok({{"status", "ok"}, {"version", FRINGE_VERSION}, {"workers", runs_->workers()},
                            {"runs", {{"running", running}, {"queued", static_cast<long>(live.size()) - running}}}});
        }
        if (top == "estimators") return get ? json_ok({{"estimators", est::registry()}}) : wrong_method("GET");
        if (top == "drivers") return get ? json_ok({{"drivers", dev::drivers()}}) : wrong_method("GET");
        if (top == "devices") return get ? devices() : wrong_method("GET");
        if (top == "fixtures") return get ? fixtures() : wrong_method("GET");
        if (top == "runs") return get ? list_runs(query) : post ? create_run(req) : wrong_method("GET, POST");
        if (top == "captures") return get ? json_ok({{"captures", captures()}}) : post ? upload_capture(req, query) : wrong_method("GET, POST");
    }
    if (seg.size() == 4 && top == "fixtures") {
        if (!get) return wrong_method("GET");
        if (auto bad = check_id(seg[3])) return *bad;
        return fixture(seg[3]);
    }
    if (top == "runs" && (seg.size() == 4 || seg.size() == 5)) {
        const std::string& id = seg[3];
        if (auto bad = check_id(id)) return *bad;
        if (seg.size() == 4) return get ? get_run(id) : wrong_method("GET");
        const std::string& what = seg[4];
        if (what == "cancel") {
            if (!post) return wrong_method("POST");
            switch (runs_->cancel(id)) {
                case RunManager::CancelResult::Cancelled: return json_ok({{"id", id}, {"cancelling", true}}, 202);
                case RunManager::CancelResult::Finished: return json_error(409, "finished", "run " + id + " has already finished");
                case RunManager::CancelResult::Unknown: break;
            }
            std::lock_guard<std::mutex> l(store_mu_);
            if (store_->row(id)) return json_error(409, "finished", "run " + id + " is not running in this service");
            return json_error(404, "not_found", "no run " + id, "id");
        }
        if (what == "events") {
            if (!get) return wrong_method("GET");
            if (!run_state(id)) return json_error(404, "not_found", "no run " + id, "id");
            HttpResponse r;
            r.events_run = id;
            r.content_type = "text/event-stream";
            return r;
        }
        if (what == "report.json" || what == "report.xml" || what == "report.html" || what == "traces") {
            if (!get) return wrong_method("GET");
            return run_artifact(id, what, query);
        }
    }
    if (top == "captures" && seg.size() == 5 && seg[4] == "evaluate") {
        if (!post) return wrong_method("POST");
        if (auto bad = check_id(seg[3])) return *bad;
        return evaluate(req, seg[3]);
    }
    return json_error(404, "not_found", "no such endpoint: " + path);
}

// ---- runs ----------------------------------------------------------------------------

json Service::sandbox_scenario(json j) const {
    if (!j.is_object()) throw ConfigError("scenario", "expected a JSON object");
    const fs::path root = fs::path(cfg_.fixtures_dir).lexically_normal();
    const fs::path base = root / "scenarios";
    if (j.contains("encoder")) check_ref(j["encoder"], base, root, "scenario.encoder");
    if (j.contains("motion") && j["motion"].is_object() && j["motion"].contains("file"))
        check_ref(j["motion"]["file"], base, root, "scenario.motion.file");
    if (j.contains("estimators") && j["estimators"].is_array())
        for (std::size_t i = 0; i < j["estimators"].size(); ++i) {
            auto& e = j["estimators"][i];
            if (!e.is_object()) continue;
            const std::string f = "scenario.estimators[" + std::to_string(i) + "]";
            if (e.contains("encoder")) check_ref(e["encoder"], base, root, f + ".encoder");
            if (e.value("name", "") == "external" && !cfg_.allow_external)
                throw ConfigError(f + ".name", "the external estimator runs a command on this host; start the service with --allow-external to permit it");
        }
    if (j.contains("device") && j["device"].is_string()) j["device"] = sandbox_device(j["device"].get<std::string>());
    return j;
}

std::string Service::sandbox_device(const std::string& uri) const {
    const std::string field = "scenario.device";
    const auto q = uri.find('?');
    const std::string query = q == std::string::npos ? "" : uri.substr(q);
    if (uri.rfind("capture:", 0) == 0) {
        const std::string id = uri.substr(8, q == std::string::npos ? std::string::npos : q - 8);
        const std::string p = valid_id(id) ? capture_path(id) : "";
        if (p.empty()) throw ConfigError(field, "capture:" + id + " is not an uploaded capture (POST /api/v1/captures, then capture:ID)");
        return "capture:" + p + query;
    }
    dev::UriParts parts;
    try {
        parts = dev::check_uri(uri);
    } catch (const ConfigError& e) {
        throw e.prefixed("scenario");
    }
    if (parts.scheme == "loopback") return uri;
    // A board profile is a file: over HTTP only the configured profiles, by name.
    if (parts.settings.contains("board") && parts.settings["board"].is_string()) {
        const std::string b = parts.settings["board"].get<std::string>();
        const auto names = dev::board_names();
        if (!valid_id(b) || std::find(names.begin(), names.end(), b) == names.end()) {
            std::string known;
            for (const auto& n : names) known += (known.empty() ? "" : ", ") + n;
            throw ConfigError(field, (valid_id(b) ? "no board profile named '" + b + "'" : std::string("over HTTP a board profile is given by name, not by path")) +
                                         " (known: " + known + "; GET /api/v1/devices lists them)");
        }
    }
    // What the allow-list matches: the device without its settings, in one spelling.
    std::string ident;
    auto refuse = [&](const std::string& why) {
        return HttpError(403, "device_not_allowed", why + "; over HTTP only loopback:, uploaded capture:ID and devices the operator allows with " +
                                                        "fringe serve --allow-device PATTERN (repeatable, glob: 'modbus+tcp://192.168.1.50:502', " +
                                                        "'modbus+rtu:/dev/ttyUSB*', 'usb:1209:*') may be used", field);
    };
    if (parts.scheme == "modbus+tcp") {
        const std::string hp = parts.path.rfind("//", 0) == 0 ? parts.path.substr(2) : parts.path;
        std::string host = hp, port = "502";
        const auto close = hp.rfind(']');
        const auto colon = hp.rfind(':');
        if (colon != std::string::npos && (hp[0] != '[' || (close != std::string::npos && colon > close))) {
            host = hp.substr(0, colon);
            port = hp.substr(colon + 1);
        }
        const bool port_ok = !port.empty() && port.size() <= 5 && std::all_of(port.begin(), port.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); }) &&
                             std::stoi(port) >= 1 && std::stoi(port) <= 65535;
        if (host.empty() || host_name(host) != lower(host) || !port_ok)
            throw ConfigError(field, "modbus+tcp needs host:port, e.g. modbus+tcp://192.168.1.50:502?board=NAME");
        ident = "modbus+tcp://" + lower(host) + ":" + std::to_string(std::stoi(port));
    } else if (parts.scheme == "modbus+rtu") {
        if (parts.path.empty() || parts.path[0] != '/' || fs::path(parts.path).lexically_normal().string() != parts.path)
            throw refuse("modbus+rtu:" + parts.path + " is not a plain serial device path");
        ident = "modbus+rtu:" + parts.path;
    } else if (parts.scheme == "usb") {
        unsigned vid = dev::usbp::kTestVid, pid = dev::usbp::kTestPid;
        if (!parts.path.empty()) {
            const auto c = parts.path.find(':');
            const auto hex4 = [](const std::string& h) {
                return !h.empty() && h.size() <= 4 && std::all_of(h.begin(), h.end(), [](char x) { return std::isxdigit(static_cast<unsigned char>(x)); });
            };
            if (c == std::string::npos || !hex4(parts.path.substr(0, c)) || !hex4(parts.path.substr(c + 1)))
                throw ConfigError(field, "usb: expects usb:VID:PID in hex (e.g. usb:1209:ec01)");
            vid = static_cast<unsigned>(std::stoul(parts.path.substr(0, c), nullptr, 16));
            pid = static_cast<unsigned>(std::stoul(parts.path.substr(c + 1), nullptr, 16));
        }
        char id[16];
        std::snprintf(id, sizeof id, "%04x:%04x", vid, pid);
        ident = std::string("usb:") + id;
    } else {
        ident = parts.scheme + ":" + parts.path;
    }
    for (const auto& pattern : cfg_.allow_devices)
        if (glob_match(pattern.substr(0, pattern.find('?')), ident)) return uri;
    throw refuse(ident + " is not on this service's device allow-list");
}

HttpResponse Service::create_run(const HttpRequest& req) {
    const json body = parse_body(req.body);
    only_keys(body, {"fixture", "scenario", "seed"}, "");
    if (body.contains("fixture") == body.contains("scenario"))
        throw ConfigError("", "give exactly one of \"fixture\" (a name from GET /api/v1/fixtures) or \"scenario\" (an object)");
    Scenario sc;
    if (body.contains("fixture")) {
        if (!body["fixture"].is_string()) throw ConfigError("fixture", "expected a string");
        const std::string name = body["fixture"].get<std::string>();
        const fs::path p = fs::path(cfg_.fixtures_dir) / "scenarios" / (name + ".json");
        if (!valid_id(name) || !fs::is_regular_file(p)) throw ConfigError("fixture", "no fixture named '" + name + "' (GET /api/v1/fixtures lists them)");
        try {
            sc = load_scenario(p.string());
        } catch (const ConfigError& e) {
            throw e.prefixed("fixture");
        }
        for (const auto& e : sc.estimators)
            if (e.name == "external" && !cfg_.allow_external)
                throw ConfigError("fixture", "this fixture uses the external estimator; start the service with --allow-external");
    } else {
        // Counted before anything is built from them (each estimator is constructed to check it).
        const json& raw = body["scenario"];
        if (raw.is_object() && raw.contains("estimators") && raw["estimators"].is_array() && raw["estimators"].size() > cfg_.max_estimators)
            return json_error(413, "too_many_estimators", "the scenario has " + std::to_string(raw["estimators"].size()) + " estimators; this service runs at most " +
                                                              std::to_string(cfg_.max_estimators) + " per run (--max-estimators)", "scenario.estimators");
        if (raw.is_object() && raw.contains("limits") && raw["limits"].is_array() && raw["limits"].size() > cfg_.max_limits)
            return json_error(413, "too_many_limits", "the scenario has " + std::to_string(raw["limits"].size()) + " limits; this service takes at most " +
                                                          std::to_string(cfg_.max_limits) + " per run (--max-limits)", "scenario.limits");
        const json safe = sandbox_scenario(body["scenario"]);
        try {
            sc = scenario_from_json(safe, (fs::path(cfg_.fixtures_dir) / "scenarios").string());
        } catch (const ConfigError& e) {
            throw e.prefixed("scenario");
        }
    }
    if (body.contains("seed")) {
        if (!body["seed"].is_number_unsigned() || body["seed"].get<std::uint64_t>() > kMaxSeed)
            throw ConfigError("seed", "expected an integer from 0 to 2^53 (9007199254740992)");
        sc.seed = body["seed"].get<std::uint64_t>();
    }
    if (auto too_big = check_run_size(sc, body.contains("fixture") ? "fixture" : "scenario")) return *too_big;
    try {
        dev::check_uri(sc.device);
        validate_run(sc);
    } catch (const ConfigError& e) {
        throw e.prefixed("scenario");
    }
    const std::string id = runs_->submit(std::move(sc));
    auto r = json_ok({{"id", id}, {"status", "queued"}, {"links", {{"self", "/api/v1/runs/" + id}, {"events", "/api/v1/runs/" + id + "/events"}}}}, 201);
    r.headers.emplace_back("Location", "/api/v1/runs/" + id);
    return r;
}

std::optional<HttpResponse> Service::check_run_size(const Scenario& sc, const std::string& field) const {
    const bool fixture = field == "fixture";
    // In double: duration_s * sample_rate_hz may not fit an integer at all.
    const double samples = sc.duration_s * sc.sample_rate_hz;
    if (!(samples <= cfg_.max_samples)) {
        char msg[256];
        std::snprintf(msg, sizeof msg, "duration_s %g s at sample_rate_hz %g Hz is %.4g samples; this service runs at most %.4g per run (--max-samples)",
                      sc.duration_s, sc.sample_rate_hz, samples, cfg_.max_samples);
        return json_error(413, "too_many_samples", msg, fixture ? field : field + ".duration_s");
    }
    if (sc.estimators.size() > cfg_.max_estimators)
        return json_error(413, "too_many_estimators", "the scenario has " + std::to_string(sc.estimators.size()) + " estimators; this service runs at most " +
                                                          std::to_string(cfg_.max_estimators) + " per run (--max-estimators)", fixture ? field : field + ".estimators");
    if (sc.limits.size() > cfg_.max_limits)
        return json_error(413, "too_many_limits", "the scenario has " + std::to_string(sc.limits.size()) + " limits; this service takes at most " +
                                                      std::to_string(cfg_.max_limits) + " per run (--max-limits)", fixture ? field : field + ".limits");
    return std::nullopt;
}

HttpResponse Service::list_runs(const std::map<std::string, std::string>& query) {
    RunFilter f;
    for (const auto& [k, v] : query) {
        if (k == "outcome" || k == "verdict") {
            static const char* verdicts[] = {"PASS", "MARGINAL", "FAIL", "ERROR", "ABORTED"};
            if (std::find(std::begin(verdicts), std::end(verdicts), v) == std::end(verdicts))  // clang 14: no structured binding in a lambda
                throw ConfigError(k, "expected PASS, MARGINAL, FAIL, ERROR or ABORTED");
            f.verdict = v;
        } else if (k == "scenario") {
            f.scenario = v;
        } else if (k == "since") {
            f.since = v;
        } else if (k == "bench") {
            f.bench = v;
        } else if (k == "dut") {
            f.dut = v;
        } else if (k == "limit") {
            try {
                std::size_t used = 0;
                f.limit = std::stoi(v, &used);
                if (used != v.size() || f.limit < 1 || f.limit > 1000) throw std::invalid_argument(v);
            } catch (const std::exception&) {
                throw ConfigError("limit", "expected an integer from 1 to 1000");
            }
        } else {
            throw ConfigError(k, "unknown query parameter (known: outcome, scenario, since, bench, dut, limit)");
        }
    }
    std::vector<RunRow> rows;
    {
        std::lock_guard<std::mutex> l(store_mu_);
        rows = store_->list(f);
    }
    json out = json::array();
    for (const auto& row : rows) {
        json j{{"id", row.id}, {"created_at", row.created_at}, {"scenario", row.scenario}, {"dut", row.dut}, {"status", row.status},
               {"bench", row.bench}, {"host", row.host}, {"dut_part", row.dut_part}};
        j["verdict"] = row.verdict.empty() ? json(nullptr) : json(row.verdict);
        if (auto s = runs_->snapshot(row.id)) {
            j["status"] = s->status;
            j["progress"] = {{"done", s->done}, {"total", s->total}};
            if (!s->verdict.empty()) j["verdict"] = s->verdict;
        }
        out.push_back(std::move(j));
    }
    return json_ok({{"runs", out}});
}

std::optional<RunSnapshot> Service::run_state(const std::string& id) {
    if (auto s = runs_->snapshot(id)) {
        s->error = public_text(s->error);
        s->device = public_text(s->device);
        return s;
    }
    std::optional<RunRow> row;
    {
        // The row's summary columns only: never the report (it can be hundreds of MB).
        std::lock_guard<std::mutex> l(store_mu_);
        row = store_->row(id);
        if (row && row->dead) store_->mark_interrupted(id);  // its process is gone: for good
    }
    if (!row) return std::nullopt;
    RunSnapshot s;
    s.id = row->id;
    s.scenario = row->scenario;
    s.dut = row->dut;
    s.created_at = row->created_at;
    s.status = row->status;
    s.verdict = row->verdict;
    s.error = public_text(row->error);
    s.done = row->done;
    s.total = row->total;
    s.device = public_text(row->device);
    s.seq = 1;
    return s;
}

HttpResponse Service::get_run(const std::string& id) {
    auto s = run_state(id);
    if (!s) return json_error(404, "not_found", "no run " + id, "id");
    json j = *s;
    const std::string base = "/api/v1/runs/" + id;
    j["links"] = {{"events", base + "/events"}, {"cancel", base + "/cancel"}};
    if (s->finished() && s->status != "interrupted")
        j["links"].update({{"report_json", base + "/report.json"}, {"report_xml", base + "/report.xml"},
                           {"report_html", base + "/report.html"}, {"traces", base + "/traces"}});
    return json_ok(j);
}

std::shared_ptr<const Service::Cached> Service::cached_report(const std::string& id) {
    {
        std::lock_guard<std::mutex> l(cache_mu_);
        if (auto it = cache_.find(id); it != cache_.end()) {
            lru_.splice(lru_.begin(), lru_, it->second.second);
            return it->second.first;
        }
    }
    std::optional<std::string> text;
    {
        std::lock_guard<std::mutex> l(store_mu_);
        text = store_->report_text(id);
    }
    if (!text) return nullptr;
    std::optional<json> rep = json::parse(*text);  // outside the store lock
    text.reset();
    auto c = std::make_shared<Cached>();
    // The service's folders by short names (capture:ID plays DATA/captures/ID.fcap).
    c->json_full = public_text(dump_safe(*rep));
    json traces = rep->contains("traces") ? (*rep)["traces"] : json::object();
    json slim = *rep;
    slim.erase("traces");
    // Plot data stays out of the plain report.json as the traces do (hundreds of KB per estimator):
    // /traces and ?traces=1 carry it.
    for (auto& e : slim["estimators"]) e.erase("spectrum");
    c->json = public_text(dump_safe(slim));
    json tr{{"id", id}, {"traces", traces}, {"estimators", json::array()}};
    for (const auto& e : (*rep)["estimators"])
        tr["estimators"].push_back({{"label", e.value("label", "")}, {"name", e.value("name", "")},
                                    {"harmonics", e.contains("metrics") ? e["metrics"].value("harmonics", json::array()) : json::array()},
                                    {"spectrum", e.value("spectrum", json())}});  // null in reports older than issue 11
    c->traces = dump_safe(tr);
    c->xml = public_text(junit_xml(*rep));
    c->html = public_text(report_html(*rep));
    std::lock_guard<std::mutex> l(cache_mu_);
    if (auto it = cache_.find(id); it != cache_.end()) return it->second.first;
    lru_.push_front(id);
    cache_[id] = {c, lru_.begin()};
    while (cache_.size() > kReportCache) {
        cache_.erase(lru_.back());
        lru_.pop_back();
    }
    return c;
}

HttpResponse Service::run_artifact(const std::string& id, const std::string& what, const std::map<std::string, std::string>& query) {
    for (const auto& [k, v] : query)
        if (!(k == "traces" && what == "report.json") && k != "download")
            throw ConfigError(k, "unknown query parameter");
    auto c = cached_report(id);
    if (!c) {
        auto s = run_state(id);
        if (!s) return json_error(404, "not_found", "no run " + id, "id");
        return json_error(409, "not_finished", "run " + id + " is " + s->status + ": its report is written when it ends");
    }
    HttpResponse r;
    if (what == "report.json") r.body = query.count("traces") && query.at("traces") != "0" ? c->json_full : c->json;
    else if (what == "traces") r.body = c->traces;
    else if (what == "report.xml") {
        r.content_type = "application/xml";
        r.body = c->xml;
    } else {
        r.content_type = "text/html; charset=utf-8";
        r.body = c->html;
        // Self-contained page: inline styles and SVG only.
        r.headers.emplace_back("Content-Security-Policy", "default-src 'none'; style-src 'unsafe-inline'; img-src data:");
    }
    if (query.count("download"))
        r.headers.emplace_back("Content-Disposition", "attachment; filename=\"fringe-" + id + "-" + (what == "traces" ? "traces.json" : what) + "\"");
    return r;
}

std::string Service::sse_event(const RunSnapshot& s) {
    std::string data;
    try {
        data = dump_safe(json(s));
    } catch (const std::exception&) {
        data = R"({"error":"the run's state could not be serialised"})";
    }
    return "id: " + std::to_string(s.seq) + "\nevent: " + (s.finished() ? "end" : "progress") + "\ndata: " + data + "\n\n";
}

// ---- catalogue ------------------------------------------------------------------------

HttpResponse Service::fixtures() {
    json list = json::array();
    const fs::path dir = fs::path(cfg_.fixtures_dir) / "scenarios";
    std::vector<fs::path> files;
    if (fs::is_directory(dir))
        for (const auto& e : fs::directory_iterator(dir))
            if (e.path().extension() == ".json") files.push_back(e.path());
    std::sort(files.begin(), files.end());
    for (const auto& p : files) {
        json f{{"name", p.stem().string()}};
        try {
            const Scenario sc = load_scenario(p.string());
            f["description"] = sc.description;
            f["device"] = sc.device;
            f["duration_s"] = sc.duration_s;
            f["sample_rate_hz"] = sc.sample_rate_hz;
            f["samples"] = sc.samples();
            json est = json::array();
            for (const auto& e : sc.estimators) est.push_back(e.label);
            f["estimators"] = est;
            f["limits"] = sc.limits.size();
            f["runnable"] = !sc.estimators.empty();
        } catch (const std::exception& e) {
            f["runnable"] = false;
            f["problem"] = public_text(e.what());
        }
        list.push_back(std::move(f));
    }
    json encoders = json::array();
    const fs::path edir = fs::path(cfg_.fixtures_dir) / "encoders";
    if (fs::is_directory(edir))
        for (const auto& e : fs::directory_iterator(edir))
            if (e.path().extension() == ".json") encoders.push_back(e.path().stem().string());
    std::sort(encoders.begin(), encoders.end());
    return json_ok({{"fixtures", list}, {"encoders", encoders}});
}

HttpResponse Service::fixture(const std::string& name) {
    const fs::path p = fs::path(cfg_.fixtures_dir) / "scenarios" / (name + ".json");
    if (!fs::is_regular_file(p)) return json_error(404, "not_found", "no fixture named '" + name + "'", "name");
    const Scenario sc = load_scenario(p.string());
    return json_ok({{"name", name}, {"scenario", sc}});
}

HttpResponse Service::devices() {
    json list = json::array();
    // Simulated and file devices are always there; hardware drivers add what they find.
    list.push_back({{"uri", "loopback:"}, {"driver", "loopback"}, {"description", "simulated DAC -> filters -> noise -> ADC"}, {"available", true}});
    for (const auto& drv : dev::drivers())
        if (drv.find)
            for (auto found : drv.find()) {
                found["driver"] = drv.scheme;
                found["available"] = true;
                list.push_back(found);
            }
    for (const auto& c : captures())
        list.push_back({{"uri", "capture:" + c["id"].get<std::string>()}, {"driver", "capture"}, {"description", "uploaded capture (" + c.value("format", "") + ")"},
                        {"available", true}});
    std::map<std::string, bool> busy;
    for (const auto& s : runs_->live())
        if (s.status == "running" && !device_key(s.device).empty()) busy[device_key(s.device)] = true;
    for (auto& d : list) d["busy"] = busy.count(device_key(d["uri"].get<std::string>())) > 0;
    // Configured board profiles: the URI to use once the board's address is known.
    json boards = json::array();
    for (const auto& name : dev::board_names()) {
        try {
            const auto b = dev::load_board(name);
            boards.push_back({{"name", b.name}, {"kind", b.kind}, {"description", b.description}, {"dut_position", b.has_dut_position()},
                              {"uri_template", "modbus+tcp://HOST:PORT?board=" + b.name}});
        } catch (const std::exception& e) {
            boards.push_back({{"name", name}, {"problem", public_text(e.what())}});
        }
    }
    return json_ok({{"devices", list}, {"boards", boards}});
}

// ---- captures -------------------------------------------------------------------------

std::string Service::capture_path(const std::string& id) const {
    for (const char* ext : {".fcap", ".csv"}) {
        const fs::path p = fs::path(cfg_.data_dir) / "captures" / (id + ext);
        if (fs::is_regular_file(p)) return fs::absolute(p).string();
    }
    return "";
}

HttpResponse Service::upload_capture(const HttpRequest& req, const std::map<std::string, std::string>& query) {
    struct Cleanup {
        std::string path;
        ~Cleanup() {
            std::error_code ec;
            if (!path.empty()) fs::remove(path, ec);
        }
    } tmp;
    std::string src = req.body_file;
    if (src.empty()) {  // handle() called with the body in memory (tests): write it out
        src = new_upload_path();
        std::ofstream(src, std::ios::binary) << req.body;
    }
    tmp.path = src;
    for (const auto& [k, v] : query)
        if (k != "format") throw ConfigError(k, "unknown query parameter (known: format)");
    std::string format;
    if (auto it = query.find("format"); it != query.end()) {
        format = it->second;
        if (format != "csv" && format != "fcap") throw ConfigError("format", "expected csv or fcap");
    } else {
        std::ifstream f(src, std::ios::binary);
        char magic[8] = {};
        f.read(magic, 8);
        format = std::string(magic, 8) == "FRNGCAP1" ? "fcap" : "csv";
    }
    if (fs::file_size(src) == 0) throw ConfigError("body", "the upload is empty");
    const std::string id = new_run_id();
    const fs::path dst = fs::path(cfg_.data_dir) / "captures" / (id + "." + format);
    fs::rename(src, dst);
    tmp.path = dst.string();
    json meta;
    double fs_hz = 0;
    CaptureData d;
    try {
        d = read_capture(dst.string(), &meta, &fs_hz);
    } catch (const CaptureError& e) {
        // Name what the client sent, not our file name.
        std::string msg = e.what();
        if (auto pos = msg.find(dst.string()); pos != std::string::npos) msg.replace(pos, dst.string().size(), "upload");
        return json_error(400, "bad_capture", msg);
    }
    const json info{{"id", id}, {"format", format}, {"samples", d.size()}, {"sample_rate_hz", fs_hz},
                    {"has_truth", !d.theta_true_rad.empty()}, {"bytes", fs::file_size(dst)}, {"uploaded_at", iso_now()}};
    write_file_atomic((fs::path(cfg_.data_dir) / "captures" / (id + ".upload.json")).string(), info.dump());
    tmp.path.clear();  // keep it
    auto r = json_ok(info, 201);
    r.headers.emplace_back("Location", "/api/v1/captures/" + id);
    return r;
}

json Service::captures() const {
    json list = json::array();
    const fs::path dir = fs::path(cfg_.data_dir) / "captures";
    std::vector<fs::path> infos;
    for (const auto& e : fs::directory_iterator(dir)) {
        const auto name = e.path().filename().string();
        if (name.size() > 12 && name.compare(name.size() - 12, 12, ".upload.json") == 0) infos.push_back(e.path());
    }
    std::sort(infos.rbegin(), infos.rend());
    for (const auto& p : infos) {
        const json j = json::parse(read_file(p), nullptr, false);
        if (!j.is_discarded()) list.push_back(j);
    }
    return list;
}

HttpResponse Service::evaluate(const HttpRequest& req, const std::string& id) {
    const std::string cap = capture_path(id);
    if (cap.empty()) return json_error(404, "not_found", "no uploaded capture " + id, "id");
    const json body = parse_body(req.body);
    only_keys(body, {"estimator", "params", "encoder", "settle_s"}, "");
    EvaluateOptions o;
    o.capture_path = cap;
    if (!body.contains("estimator") || !body["estimator"].is_string()) throw ConfigError("estimator", "expected an estimator name (GET /api/v1/estimators)");
    o.estimator = body["estimator"].get<std::string>();
    est::find(o.estimator);  // throws ConfigError naming the known ones
    if (o.estimator == "external" && !cfg_.allow_external)
        throw ConfigError("estimator", "the external estimator runs a command on this host; start the service with --allow-external");
    if (body.contains("params")) {
        if (!body["params"].is_object()) throw ConfigError("params", "expected an object");
        o.params = body["params"];
    }
    if (body.contains("settle_s")) {
        if (!body["settle_s"].is_number() || body["settle_s"].get<double>() < 0) throw ConfigError("settle_s", "expected a number >= 0");
        o.settle_s = body["settle_s"].get<double>();
    }
    if (body.contains("encoder")) {
        json enc = body["encoder"];
        if (enc.is_string()) {
            const std::string name = enc.get<std::string>();
            const fs::path p = fs::path(cfg_.fixtures_dir) / "encoders" / (name + ".json");
            if (!valid_id(name) || !fs::is_regular_file(p)) throw ConfigError("encoder", "no encoder fixture named '" + name + "'");
            o.encoder = load_encoder(p.string());
        } else {
            o.encoder = encoder_from_json(enc, "encoder");
        }
    }
    json rep = evaluate_capture(o);
    rep["capture"] = id;
    return json_ok(rep);
}

}  // namespace fringe
