// The service's guards (service.hpp): the API token and its file, the Host check against DNS
// rebinding, and the sandbox for clients' scenarios (file references, device allow-list), with
// the service's own paths hidden in what clients read.
#include "server/http/service_internal.hpp"

#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "drivers/usb_protocol.hpp"
#include "estimator/estimator.hpp"
#include "server/engine/scenario.hpp"

#include <spdlog/spdlog.h>

#include <arpa/inet.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <random>

namespace fringe {

using namespace service_detail;

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

json Service::sandbox_scenario(json j) const {
    if (!j.is_object()) throw ConfigError("scenario", "expected a JSON object");
    const fs::path root = fs::path(cfg_.fixtures_dir).lexically_normal();
    const fs::path base = root / "scenarios";
    if (j.contains("encoder")) check_ref(j["encoder"], base, root, "scenario.encoder");
    if (j.contains("interface")) check_ref(j["interface"], base, root, "scenario.interface");
    if (j.contains("motion") && j["motion"].is_object() && j["motion"].contains("file"))
        check_ref(j["motion"]["file"], base, root, "scenario.motion.file");
    if (j.contains("estimators") && j["estimators"].is_array())
        for (std::size_t i = 0; i < j["estimators"].size(); ++i) {
            auto& e = j["estimators"][i];
            if (!e.is_object()) continue;
            const std::string f = "scenario.estimators[" + std::to_string(i) + "]";
            if (e.contains("encoder")) check_ref(e["encoder"], base, root, f + ".encoder");
            // A correction file (docs/calibration.md) is a file on this host: a fixture, like the
            // encoder (an absolute path read any file, and its parse error quoted it).
            if (e.contains("params") && e["params"].is_object() && e["params"].contains("correction"))
                check_ref(e["params"]["correction"], base, root, f + ".params.correction", false);
            const std::string name = e.contains("name") && e["name"].is_string() ? e["name"].get<std::string>() : "";
            if (est::traits_of(name).child_process && !cfg_.allow_external)
                throw ConfigError(f + ".name", "the " + name + " estimator runs a command on this host; start the service with --allow-external to permit it");
        }
    // A calibrated run's after pass (docs/calibration.md): its motion file and its device are held
    // to the same policy as the scenario's own.
    if (j.contains("calibrate") && j["calibrate"].is_object() && j["calibrate"].contains("verify") && j["calibrate"]["verify"].is_object()) {
        auto& v = j["calibrate"]["verify"];
        if (v.contains("motion") && v["motion"].is_object() && v["motion"].contains("file"))
            check_ref(v["motion"]["file"], base, root, "scenario.calibrate.verify.motion.file");
        if (v.contains("device") && v["device"].is_string())
            v["device"] = sandbox_device(v["device"].get<std::string>(), "scenario.calibrate.verify.device");
        else if (v.contains("device") && !v["device"].is_null())
            throw ConfigError("scenario.calibrate.verify.device", "expected a device URI (a string)");
    }
    if (j.contains("device") && j["device"].is_string()) j["device"] = sandbox_device(j["device"].get<std::string>());
    // Output and input instruments: each on its own is held to the same policy.
    if (j.contains("device") && j["device"].is_object())
        for (const char* k : {"output", "input", "dut"})
            if (j["device"].contains(k) && j["device"][k].is_string())
                j["device"][k] = sandbox_device(j["device"][k].get<std::string>(), std::string("scenario.device.") + k);
    return j;
}

std::string Service::sandbox_device(const std::string& uri, const std::string& field) const {
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
        const std::string f = e.field();  // "device" or "device.<setting>": under this URI's field
        throw ConfigError(f.rfind("device", 0) == 0 ? field + f.substr(6) : field, e.message());
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

}  // namespace fringe
