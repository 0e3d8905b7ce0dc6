#include "device.hpp"

#include "signal_gen/base/config.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <sys/file.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cctype>
#include <climits>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

namespace fringe::dev {

void register_loopback(std::vector<DriverInfo>& r);
void register_capture(std::vector<DriverInfo>& r);
void register_modbus(std::vector<DriverInfo>& r);
void register_usb(std::vector<DriverInfo>& r);
void register_scpi(std::vector<DriverInfo>& r);
void register_readout(std::vector<DriverInfo>& r);
void register_sigrok(std::vector<DriverInfo>& r);

const char* to_string(StreamStatus s) {
    switch (s) {
        case StreamStatus::Ok: return "ok";
        case StreamStatus::Timeout: return "timeout";
        case StreamStatus::Overflow: return "overflow";
        case StreamStatus::Underflow: return "underflow";
        case StreamStatus::Error: return "error";
    }
    return "?";
}

std::vector<std::string> DeviceInfo::ports() const {
    std::vector<std::string> p;
    if (streaming) p.push_back("stream");
    if (step_mode) p.push_back("step");
    if (can_play) p.push_back("play");
    if (can_record) p.push_back("record");
    if (replay) p.push_back("replay");
    if (readout) p.push_back("readout");
    return p;
}

DeviceInfo Device::info() const {
    DeviceInfo i = describe();
    // The ports are asked, not the driver's word: a flag cannot claim what the device lacks.
    auto& self = const_cast<Device&>(*this);
    i.streaming = self.stream() != nullptr;
    i.step_mode = self.step() != nullptr;
    PlayPort* play = self.player();
    i.can_play = play != nullptr;
    i.max_play_samples = play ? play->memory_samples() : 0;
    i.can_record = self.recorder() != nullptr;
    i.replay = self.replay() != nullptr;
    i.readout = self.readout() != nullptr;
    return i;
}

void to_json(nlohmann::json& j, const DeviceInfo& d) {
    // "streaming": frames arrive as a stream, live (a StreamPort) or replayed (a ReplayPort),
    // as reports before the ports said; "ports" names each.
    j = {{"driver", d.driver}, {"uri", d.uri}, {"description", d.description}, {"board_id", d.board_id},
         {"streaming", d.streaming || d.replay}, {"step_mode", d.step_mode}, {"dut_position", d.dut_position}, {"ports", d.ports()},
         {"latency_samples", d.latency_samples}, {"settings", d.settings}, {"converter", d.converter}};
    if (d.can_play || d.can_record) {
        j["can_play"] = d.can_play;
        j["can_record"] = d.can_record;
        j["own_clock"] = d.own_clock;
        j["max_play_samples"] = d.max_play_samples;
    }
}

void to_json(nlohmann::json& j, const ConverterInfo& c) {
    j = {{"known", c.known}, {"dac_bits", c.dac_bits}, {"dac_range_v", c.dac_range_v}, {"adc_bits", c.adc_bits},
         {"adc_range_v", c.adc_range_v}, {"dac_step_v", c.dac_q_v()}, {"adc_step_v", c.adc_q_v()}, {"noise_at_adc_v", c.noise_at_adc_v}, {"added_noise_v", c.added_noise_v}};
    if (!c.note.empty()) j["note"] = c.note;
}

void to_json(nlohmann::json& j, const DriverInfo& d) {
    j = {{"scheme", d.scheme}, {"summary", d.summary}, {"settings", d.settings}};
}

const std::vector<DriverInfo>& drivers() {
    static const std::vector<DriverInfo> all = [] {
        std::vector<DriverInfo> r;
        register_loopback(r);
        register_capture(r);
        register_modbus(r);
        register_usb(r);
        register_scpi(r);
        register_readout(r);
        register_sigrok(r);
        return r;
    }();
    return all;
}

namespace {
struct ParsedUri {
    const DriverInfo* drv;
    std::string path;
    nlohmann::json settings;
};

ParsedUri parse_uri(const std::string& uri) {
    const auto colon = uri.find(':');
    if (colon == std::string::npos || colon == 0)
        throw ConfigError("device", "'" + uri + "' is not a device URI (scheme:path?key=value, e.g. loopback:)");
    const std::string scheme = uri.substr(0, colon);
    std::string rest = uri.substr(colon + 1), query;
    if (const auto q = rest.find('?'); q != std::string::npos) {
        query = rest.substr(q + 1);
        rest = rest.substr(0, q);
    }
    const DriverInfo* drv = nullptr;
    for (const auto& d : drivers())
        if (d.scheme == scheme) drv = &d;
    if (!drv) {
        std::string known;
        for (const auto& d : drivers()) known += (known.empty() ? "" : ", ") + d.scheme;
        throw ConfigError("device", "unknown driver '" + scheme + "' (known: " + known + ")");
    }
    std::vector<std::string> kv;
    std::size_t pos = 0;
    while (pos < query.size()) {
        auto amp = query.find('&', pos);
        if (amp == std::string::npos) amp = query.size();
        if (amp > pos) kv.push_back(query.substr(pos, amp - pos));
        pos = amp + 1;
    }
    const nlohmann::json given = parse_param_assignments(drv->settings, kv, "device");
    const Params p = resolve_params(drv->settings, given, "device");
    return {drv, rest, p.json()};
}
}  // namespace

UriParts check_uri(const std::string& uri) {
    auto p = parse_uri(uri);
    return {p.drv->scheme, p.path, p.settings};
}

std::unique_ptr<Device> open(const std::string& uri) {
    auto p = parse_uri(uri);
    // The lock is taken before the driver touches the device (connects, writes its init).
    const std::string key = DeviceLock::key_for(uri);
    std::shared_ptr<DeviceLock> lock = key.empty() ? nullptr : DeviceLock::acquire(key, uri);
    auto d = p.drv->open(uri, p.path, p.settings);
    d->lock_ = std::move(lock);
    return d;
}

namespace {

// host[:port] of a URI path ("//host:port" or "host:port"), port defaulting to def.
std::pair<std::string, std::string> host_port(const std::string& path, const std::string& def) {
    std::string hp = path.rfind("//", 0) == 0 ? path.substr(2) : path;
    if (const auto slash = hp.find('/'); slash != std::string::npos) hp = hp.substr(0, slash);
    if (!hp.empty() && hp[0] == '[') {  // [v6]:port
        const auto close = hp.find(']');
        if (close != std::string::npos)
            return {hp.substr(1, close - 1), close + 1 < hp.size() && hp[close + 1] == ':' ? hp.substr(close + 2) : def};
    }
    const auto colon = hp.rfind(':');
    if (colon == std::string::npos || hp.find(':') != colon) return {hp, def};
    return {hp.substr(0, colon), hp.substr(colon + 1)};
}

// The address a host name or literal resolves to (its first), as text; the name itself when it
// does not resolve (the driver's connect then names the failure).
std::string resolve_host(const std::string& host) {
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* res = nullptr;
    if (getaddrinfo(host.c_str(), nullptr, &hints, &res) != 0 || !res) return host;
    char buf[INET6_ADDRSTRLEN] = {0};
    std::string out = host;
    if (res->ai_family == AF_INET)
        out = inet_ntop(AF_INET, &reinterpret_cast<sockaddr_in*>(res->ai_addr)->sin_addr, buf, sizeof buf) ? buf : host;
    else if (res->ai_family == AF_INET6)
        out = inet_ntop(AF_INET6, &reinterpret_cast<sockaddr_in6*>(res->ai_addr)->sin6_addr, buf, sizeof buf) ? buf : host;
    freeaddrinfo(res);
    return out;
}

std::string real_path(const std::string& path) {
    char buf[PATH_MAX];
    return ::realpath(path.c_str(), buf) ? std::string(buf) : path;
}

// A file name for a key: its safe characters and a hash of the whole (no two keys share one).
std::string lock_file_name(const std::string& key) {
    std::uint64_t h = 1469598103934665603ull;  // FNV-1a
    for (unsigned char c : key) h = (h ^ c) * 1099511628211ull;
    std::string safe;
    for (char c : key) safe += std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' ? c : '_';
    if (safe.size() > 120) safe.resize(120);
    char hex[20];
    std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(h));
    return safe + "-" + hex + ".lock";
}

std::string this_command() {
    std::ifstream f("/proc/self/cmdline", std::ios::binary);
    std::string raw((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>()), out;
    for (char c : raw) out += c == '\0' ? ' ' : c;
    while (!out.empty() && out.back() == ' ') out.pop_back();
    if (out.size() > 200) out = out.substr(0, 197) + "...";
    return out;
}

struct Held {
    std::weak_ptr<DeviceLock> lock;
    std::thread::id owner;
};
std::mutex g_held_mu;
std::map<std::string, Held>& held() {
    static std::map<std::string, Held> m;
    return m;
}

}  // namespace

std::string DeviceLock::lock_dir() {
    if (const char* d = std::getenv("FRINGE_LOCK_DIR"); d && *d) return d;
    if (::access("/run/lock", W_OK | X_OK) == 0) return "/run/lock/fringe";
    return "/tmp/fringe-locks";
}

std::string DeviceLock::key_for(const std::string& uri) {
    const auto p = parse_uri(uri);
    const std::string& scheme = p.drv->scheme;
    if (scheme == "modbus+tcp") {
        const auto [host, port] = host_port(p.path, "502");
        return "modbus-tcp:" + resolve_host(host) + ":" + port + ":unit" + std::to_string(p.settings.value("unit", 1));
    }
    if (scheme == "modbus+rtu") return "serial:" + real_path(p.path);
    if (scheme == "scpi+tcp") {
        const auto [host, port] = host_port(p.path, "5025");
        return "tcp:" + resolve_host(host) + ":" + port;
    }
    if (scheme == "usb" || scheme == "scpi+usbtmc") {
        std::string vp = p.path.empty() ? "1209:ec01" : p.path;
        for (auto& c : vp) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        // Not the serial: a URI without one opens the first board found, which may be the one
        // another run named by serial. Every board of one VID:PID is one owner at a time.
        return "usb:" + vp;
    }
    // sigrok: the driver and its connection as sigrok-cli -d names them; the demo driver is
    // generated per process, nothing to own.
    if (scheme == "sigrok") return p.path.empty() || p.path == "demo" || p.path.rfind("demo:", 0) == 0 ? "" : "sigrok:" + p.path;
    return "";  // loopback, capture: nothing outside this run can drive them
}

std::shared_ptr<DeviceLock> DeviceLock::acquire(const std::string& key, const std::string& device) {
    std::lock_guard<std::mutex> g(g_held_mu);
    auto& m = held();
    if (auto it = m.find(key); it != m.end()) {
        if (auto l = it->second.lock.lock()) {
            if (it->second.owner == std::this_thread::get_id()) return l;  // this run opens it twice
            throw DeviceError(device, "busy: " + key + " is in use by another run of this process (pid " + std::to_string(::getpid()) + ", " + this_command() + ")");
        }
        m.erase(it);
    }
    const std::string dir = lock_dir();
    if (::mkdir(dir.c_str(), 01777) == 0) ::chmod(dir.c_str(), 01777);  // shared by every user of the bench
    const std::string path = dir + "/" + lock_file_name(key);
    int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0666);
    if (fd >= 0) ::fchmod(fd, 0666);  // umask: another user must be able to open it too (fails harmlessly if not ours)
    if (fd < 0) fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) throw DeviceError(device, "cannot open the device lock " + path + ": " + std::strerror(errno) + " (set FRINGE_LOCK_DIR to a writable directory)");
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
        const int e = errno;
        std::string holder;
        // The holder writes its pid and command just after it locks: wait briefly for them.
        for (int i = 0; i < 20 && holder.empty(); ++i) {
            char buf[512];
            const ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
            if (n > 0) holder.assign(buf, static_cast<std::size_t>(n));
            while (!holder.empty() && (holder.back() == '\n' || holder.back() == '\0')) holder.pop_back();
            if (holder.empty()) std::this_thread::sleep_for(std::chrono::milliseconds(5));
        }
        ::close(fd);
        if (e != EWOULDBLOCK) throw DeviceError(device, "cannot lock " + path + ": " + std::strerror(e));
        throw DeviceError(device, "busy: " + key + " is in use by " + (holder.empty() ? "another process" : holder) + " (lock " + path + ")");
    }
    const std::string who = "pid " + std::to_string(::getpid()) + " (command " + this_command() + ")\n";
    if (::ftruncate(fd, 0) == 0) {
        const ssize_t w = ::pwrite(fd, who.data(), who.size(), 0);
        (void)w;  // a read-only lock file (another user's) still locks; the holder is then unnamed
    }
    std::shared_ptr<DeviceLock> l(new DeviceLock(key, fd));
    m[key] = {l, std::this_thread::get_id()};
    return l;
}

DeviceLock::~DeviceLock() {
    if (fd_ >= 0) {
        if (::ftruncate(fd_, 0) != 0) {}  // the holder's name goes with the lock
        ::close(fd_);  // releases the flock
    }
}

std::string num(double v) {
    char b[40];
    std::snprintf(b, sizeof b, "%.10g", v);
    return b;
}

}  // namespace fringe::dev
