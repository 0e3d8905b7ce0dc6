#include "sigrok_live.hpp"

#include "signal_gen/base/config.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <set>
#include <sstream>
#include <thread>

namespace fringe::dev {

namespace {

constexpr std::size_t kStderrTail = 2048;
constexpr std::size_t kReadChunk = 1 << 16;

// libsigrok 0.5.2 / sigrok-cli 0.7.2 (Debian 12) end every `-O analog` acquisition with this
// glib assertion and exit status 1 after all samples were written (measured: `sigrok-cli -d
// demo --samples 6 -O analog; echo $?`). It is accepted as the end only when every asked-for
// sample arrived and it is the only thing on stderr.
constexpr const char* kAnalogTeardown = "g_atomic_ref_count_dec: assertion 'old_value > 0' failed";

void append_tail(std::string& tail, const char* p, std::size_t n) {
    tail.append(p, n);
    if (tail.size() > kStderrTail) tail.erase(0, tail.size() - kStderrTail);
}

std::string trimmed(std::string s) {
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.pop_back();
    std::size_t i = 0;
    while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    return s.substr(i);
}

// Spawns argv (no shell) in a process group of its own, stdout and stderr to pipes (the
// parent's ends non-blocking, close-on-exec); every other descriptor is closed in the child.
// stdin is a pipe whose write end the parent keeps open and never writes (in_fd): sigrok-cli
// --continuous stops at its first "key press", and /dev/null reads as one at once (measured: 0
// bytes, exit 0). Returns the pid, or -1 with the error in `error`.
pid_t spawn(const std::vector<std::string>& argv, int& in_fd, int& out_fd, int& err_fd, std::string& error) {
    int in[2] = {-1, -1}, out[2] = {-1, -1}, err[2] = {-1, -1};
    if (::pipe2(in, O_CLOEXEC) != 0 || ::pipe2(out, O_CLOEXEC) != 0 || ::pipe2(err, O_CLOEXEC) != 0) {
        error = std::string("pipe: ") + std::strerror(errno);
        for (int fd : {in[0], in[1], out[0], out[1], err[0], err[1]})
            if (fd >= 0) ::close(fd);
        return -1;
    }
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, in[0], 0);
    posix_spawn_file_actions_adddup2(&fa, out[1], 1);
    posix_spawn_file_actions_adddup2(&fa, err[1], 2);
    posix_spawn_file_actions_addclosefrom_np(&fa, 3);
    posix_spawnattr_t attr;
    posix_spawnattr_init(&attr);
    sigset_t none, defaults;
    sigemptyset(&none);
    sigemptyset(&defaults);
    for (int s : {SIGPIPE, SIGTERM, SIGINT, SIGHUP, SIGCHLD, SIGQUIT}) sigaddset(&defaults, s);
    posix_spawnattr_setsigmask(&attr, &none);
    posix_spawnattr_setsigdefault(&attr, &defaults);
    posix_spawnattr_setpgroup(&attr, 0);
    posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETPGROUP | POSIX_SPAWN_SETSIGMASK | POSIX_SPAWN_SETSIGDEF);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    pid_t pid = -1;
    const bool has_slash = argv[0].find('/') != std::string::npos;
    const int rc = has_slash ? ::posix_spawn(&pid, args[0], &fa, &attr, args.data(), environ)
                             : ::posix_spawnp(&pid, args[0], &fa, &attr, args.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    posix_spawnattr_destroy(&attr);
    ::close(in[0]);
    ::close(out[1]);
    ::close(err[1]);
    if (rc != 0) {
        error = "cannot run '" + argv[0] + "': " + std::strerror(rc);
        ::close(in[1]);
        ::close(out[0]);
        ::close(err[0]);
        return -1;
    }
    in_fd = in[1];
    ::fcntl(out[0], F_SETFL, ::fcntl(out[0], F_GETFL) | O_NONBLOCK);
    ::fcntl(err[0], F_SETFL, ::fcntl(err[0], F_GETFL) | O_NONBLOCK);
    out_fd = out[0];
    err_fd = err[0];
    return pid;
}

std::string status_text(int st) {
    if (WIFEXITED(st)) return "exited with status " + std::to_string(WEXITSTATUS(st));
    if (WIFSIGNALED(st)) {
        const char* n = sigabbrev_np(WTERMSIG(st));
        return "killed by signal " + std::to_string(WTERMSIG(st)) + (n ? std::string(" (SIG") + n + ")" : "");
    }
    return "status " + std::to_string(st);
}

// Waits up to wait_ms for pid to exit by itself, then sends its group SIGTERM (and SIGCONT, for
// a stopped group), SIGKILL after another second; reaps it and returns its wait status.
int wait_or_kill(pid_t pid, int wait_ms) {
    int st = 0;
    auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(wait_ms);
    for (int phase = 0; phase < 2; ++phase) {
        while (true) {
            const pid_t r = ::waitpid(pid, &st, WNOHANG);
            if (r == pid) return st;
            if (r < 0 && errno != EINTR) return -1;
            if (std::chrono::steady_clock::now() >= until) break;
            std::this_thread::sleep_for(std::chrono::milliseconds(2));
        }
        if (phase == 0) {
            ::kill(-pid, SIGTERM);
            ::kill(-pid, SIGCONT);
            until = std::chrono::steady_clock::now() + std::chrono::milliseconds(1000);
        }
    }
    ::kill(-pid, SIGKILL);
    while (::waitpid(pid, &st, 0) < 0) {
        if (errno != EINTR) return -1;
    }
    return st;
}

// The value of an `-O analog` number and unit in the unit's base SI unit ("3.0902 V", "0.0 mV",
// "12 µA"); the unit itself is not checked (a scope reports V, a DMM A or Ohm).
bool parse_analog_value(const std::string& rest, double& v) {
    const char* s = rest.c_str();
    char* end = nullptr;
    errno = 0;
    v = std::strtod(s, &end);
    if (end == s) return false;
    std::string unit = trimmed(std::string(end));
    if (const auto sp = unit.find(' '); sp != std::string::npos) unit = unit.substr(0, sp);
    if (unit.size() < 2) return true;
    static const std::pair<const char*, double> prefixes[] = {{"µ", 1e-6}, {"u", 1e-6}, {"n", 1e-9}, {"p", 1e-12}, {"m", 1e-3},
                                                              {"k", 1e3},  {"M", 1e6},  {"G", 1e9}};
    for (const auto& [p, f] : prefixes) {
        const std::size_t n = std::strlen(p);
        if (unit.size() > n && unit.compare(0, n, p) == 0) {
            v *= f;
            break;
        }
    }
    return true;
}

// Runs argv to its end (at most timeout_ms), its stdout in text (up to 1 MiB), the tail of its
// stderr in etail; the wait status, timed_out when it had to be killed.
int run_collect(const std::string& name, const std::vector<std::string>& argv, int timeout_ms, std::string& text, std::string& etail, bool& timed_out) {
    int in = -1, out = -1, err = -1;
    std::string error;
    const pid_t pid = spawn(argv, in, out, err, error);
    if (pid < 0) throw DeviceError(name, error);
    const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
    bool out_open = true, err_open = true;
    timed_out = false;
    char b[4096];
    while (out_open || err_open) {
        const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(until - std::chrono::steady_clock::now()).count();
        if (left <= 0) {
            timed_out = true;
            break;
        }
        pollfd p[2] = {{out_open ? out : -1, POLLIN, 0}, {err_open ? err : -1, POLLIN, 0}};
        if (::poll(p, 2, static_cast<int>(left)) < 0 && errno != EINTR) break;
        for (int i = 0; i < 2; ++i) {
            if (!(p[i].revents & (POLLIN | POLLHUP | POLLERR))) continue;
            const ssize_t n = ::read(p[i].fd, b, sizeof b);
            if (n > 0) {
                if (i == 0 && text.size() < (1u << 20)) text.append(b, static_cast<std::size_t>(n));
                if (i == 1) append_tail(etail, b, static_cast<std::size_t>(n));
            } else if (n == 0 || (errno != EAGAIN && errno != EINTR)) {
                (i == 0 ? out_open : err_open) = false;
            }
        }
    }
    ::close(in);
    ::close(out);
    ::close(err);
    return wait_or_kill(pid, timed_out ? 0 : 2000);
}

}  // namespace

SigrokLive::SigrokLive(SigrokLiveConfig cfg)
    : cfg_(std::move(cfg)), name_("sigrok:" + (cfg_.input_file.empty() ? cfg_.driver : cfg_.input_file)) {
    validate();
}

SigrokLive::~SigrokLive() { stop(); }

void SigrokLive::validate() const {
    if (!cfg_.input_file.empty()) {
        if (!cfg_.driver.empty()) throw DeviceError(name_, "a driver and an input file at once: one source per acquisition");
        if (!cfg_.analog_channels.empty())
            throw DeviceError(name_,
                              "a replayed session is read as logic only: sigrok-cli -O analog prints a session's samples with the digits its "
                              "source declared (a demo recording: 2 decimals, 10 mV steps), where capture:x.sr reads them exactly");
        if (!cfg_.config.empty() || !cfg_.channel_group.empty()) throw DeviceError(name_, "a replayed session takes no device --config or channel group");
        if (cfg_.limit_samples) throw DeviceError(name_, "a replayed session ends with its own sample count (no limit_samples)");
    } else if (cfg_.driver.empty()) {
        throw DeviceError("sigrok:", "no driver named (sigrok-cli -d: demo, fx2lafw, fx2lafw:conn=1.5, ...)");
    }
    const bool file_rate = !cfg_.input_file.empty() && cfg_.samplerate_hz == 0;  // the file's own, from --show
    if (!file_rate && (!(cfg_.samplerate_hz > 0) || !std::isfinite(cfg_.samplerate_hz)))
        throw DeviceError(name_, "samplerate must be > 0 Hz (got " + num(cfg_.samplerate_hz) + ")");
    if (cfg_.samplerate_hz != std::floor(cfg_.samplerate_hz) || cfg_.samplerate_hz > 1e15)
        throw DeviceError(name_, "samplerate must be a whole number of Hz (got " + num(cfg_.samplerate_hz) + ")");
    if (cfg_.logic_channels.empty() && cfg_.analog_channels.empty()) throw DeviceError(name_, "no channels named (logic_channels or analog_channels)");
    if (!cfg_.logic_channels.empty() && !cfg_.analog_channels.empty())
        throw DeviceError(name_,
                          "logic and analog channels in one acquisition: sigrok-cli 0.7 has no output module that streams both (csv mislabels "
                          "and garbles mixed packets); use one SigrokLive per kind");
    if (cfg_.logic_channels.size() > 64) throw DeviceError(name_, "at most 64 logic channels (one 64-bit word per sample)");
    std::set<std::string> seen;
    for (const auto* list : {&cfg_.logic_channels, &cfg_.analog_channels})
        for (const auto& c : *list) {
            if (c.empty() || c.find_first_of(",:= \t\n") != std::string::npos) throw DeviceError(name_, "bad channel name '" + c + "'");
            if (!seen.insert(c).second) throw DeviceError(name_, "channel '" + c + "' named twice");
        }
    for (const auto& [k, v] : cfg_.config) {
        if (k.empty() || k.find_first_of(":= ") != std::string::npos || v.find(':') != std::string::npos)
            throw DeviceError(name_, "bad --config entry '" + k + "=" + v + "'");
        if (k == "samplerate" || k == "limit_samples" || k == "continuous")
            throw DeviceError(name_, "--config " + k + " is set from the configuration's own field, not from config");
    }
    if (cfg_.program.empty()) throw DeviceError(name_, "no program (sigrok-cli)");
}

std::vector<std::string> SigrokLive::command() const {
    if (!cfg_.input_file.empty()) return {cfg_.program, "-i", cfg_.input_file, "-O", "binary"};  // -i ignores --channels
    std::vector<std::string> a{cfg_.program, "-d", cfg_.driver};
    if (!cfg_.channel_group.empty()) a.insert(a.end(), {"-g", cfg_.channel_group});
    std::string conf;
    if (cfg_.channel_group.empty()) conf = "samplerate=" + num(cfg_.samplerate_hz);
    for (const auto& [k, v] : cfg_.config) conf += (conf.empty() ? "" : ":") + k + "=" + v;
    if (!conf.empty()) a.insert(a.end(), {"--config", conf});
    // Logic: the device's channels from its first through the highest one named are enabled, so
    // the binary unit is laid out the same whether a driver packs the enabled channels into the
    // low bits (the demo driver, measured) or keeps each at its channel index (libsigrok's
    // convention, fx2lafw); the channels not named are dropped here.
    std::string chans;
    if (analog_mode()) {
        for (const auto& c : cfg_.analog_channels) chans += (chans.empty() ? "" : ",") + c;
    } else {
        std::size_t hi = 0;
        for (const auto& c : cfg_.logic_channels)
            hi = std::max(hi, static_cast<std::size_t>(std::find(device_channels_.begin(), device_channels_.end(), c) - device_channels_.begin()));
        if (device_channels_.empty())
            for (const auto& c : cfg_.logic_channels) chans += (chans.empty() ? "" : ",") + c;
        else
            for (std::size_t i = 0; i <= hi && i < device_channels_.size(); ++i) chans += (chans.empty() ? "" : ",") + device_channels_[i];
    }
    a.insert(a.end(), {"--channels", chans});
    if (cfg_.limit_samples)
        a.insert(a.end(), {"--samples", std::to_string(cfg_.limit_samples)});
    else
        a.push_back("--continuous");
    a.insert(a.end(), {"-O", analog_mode() ? "analog" : "binary"});
    return a;
}

void SigrokLive::scan() {
    if (!cfg_.input_file.empty()) return show_file();
    std::vector<std::string> argv{cfg_.program, "-d", cfg_.driver, "--scan"};
    std::string text, etail;
    bool timed_out = false;
    const int st = run_collect(name_, argv, cfg_.scan_timeout_ms, text, etail, timed_out);
    const std::string why = trimmed(etail);
    if (timed_out)
        throw DeviceError(name_, "'" + cfg_.program + " -d " + cfg_.driver + " --scan' did not finish within " + std::to_string(cfg_.scan_timeout_ms) + " ms" +
                                     (why.empty() ? "" : ": " + why));
    // "demo - Demo device with 13 channels: D0 D1 ... A4"
    std::istringstream lines(text);
    std::string line;
    while (std::getline(lines, line)) {
        const auto at = line.find(" channels: ");
        if (at == std::string::npos) continue;
        std::istringstream names(line.substr(at + 11));
        std::string n;
        while (names >> n) device_channels_.push_back(n);
        break;
    }
    if (device_channels_.empty())
        throw DeviceError(name_, "sigrok-cli found no device for driver '" + cfg_.driver + "' (" + status_text(st) + ")" + (why.empty() ? "" : ": " + why));
}

// `sigrok-cli -i FILE --show`:
//   Samplerate: 100000 / Channels: 8 / - D0: logic / ... / Logic unitsize: 1 / Logic sample count: 1000
void SigrokLive::show_file() {
    // sigrok-cli would block on a FIFO's open and reads "not a regular file" for a missing one.
    struct stat fst;
    if (::stat(cfg_.input_file.c_str(), &fst) != 0) throw DeviceError(name_, cfg_.input_file + ": " + std::strerror(errno));
    if (!S_ISREG(fst.st_mode)) throw DeviceError(name_, cfg_.input_file + ": not a regular file (a session is replayed from a file)");
    std::vector<std::string> argv{cfg_.program, "-i", cfg_.input_file, "--show"};
    std::string text, etail;
    bool timed_out = false;
    const int st = run_collect(name_, argv, cfg_.scan_timeout_ms, text, etail, timed_out);
    const std::string why = trimmed(etail);
    const std::string cmd = "'" + cfg_.program + " -i " + cfg_.input_file + " --show'";
    if (timed_out) throw DeviceError(name_, cmd + " did not finish within " + std::to_string(cfg_.scan_timeout_ms) + " ms" + (why.empty() ? "" : ": " + why));
    double rate = 0;
    std::uint64_t count = 0;
    std::size_t unitsize = 0;
    bool has_count = false;
    std::istringstream lines(text);
    std::string line;
    auto number_after = [&](const char* key, double& v) {
        if (line.rfind(key, 0) != 0) return false;
        const std::string t = trimmed(line.substr(std::strlen(key)));
        char* end = nullptr;
        v = std::strtod(t.c_str(), &end);
        return end && *end == '\0' && !t.empty();
    };
    while (std::getline(lines, line)) {
        double v = 0;
        if (number_after("Samplerate:", v)) rate = v;
        else if (number_after("Logic unitsize:", v) && v >= 1 && v <= 8) unitsize = static_cast<std::size_t>(v);
        else if (number_after("Logic sample count:", v) && v >= 0) count = static_cast<std::uint64_t>(v), has_count = true;
        else if (line.rfind("- ", 0) == 0 && line.size() > 9 && line.compare(line.size() - 7, 7, ": logic") == 0)
            device_channels_.push_back(line.substr(2, line.size() - 9));
    }
    if (!WIFEXITED(st) || WEXITSTATUS(st) != 0 || device_channels_.empty() || unitsize == 0)
        throw DeviceError(name_, cmd + " found no logic session (" + status_text(st) + ")" + (why.empty() ? "" : ": " + why));
    if (!(rate > 0)) throw DeviceError(name_, cfg_.input_file + ": the session has no samplerate");
    // A negative rate in the metadata reads back as 2^64 - |rate|: the reader's own range.
    if (!(rate >= 1 && rate <= 1e10)) throw DeviceError(name_, cfg_.input_file + ": samplerate " + num(rate) + " Hz is not a rate in [1 Hz, 10 GHz]");
    if (cfg_.samplerate_hz > 0 && cfg_.samplerate_hz != rate)
        throw DeviceError(name_, cfg_.input_file + ": recorded at " + num(rate) + " Hz, not the " + num(cfg_.samplerate_hz) + " Hz asked for");
    cfg_.samplerate_hz = rate;
    file_unitsize_ = unitsize;
    if (has_count) {
        if (count == 0) throw DeviceError(name_, cfg_.input_file + ": the session holds no logic sample");
        cfg_.limit_samples = count;
    }
}

void SigrokLive::probe() {
    if (probed_) return;
    scan();
    std::string all;
    for (const auto& c : device_channels_) all += (all.empty() ? "" : " ") + c;
    for (const auto* list : {&cfg_.logic_channels, &cfg_.analog_channels})
        for (const auto& c : *list)
            if (std::find(device_channels_.begin(), device_channels_.end(), c) == device_channels_.end())
                throw DeviceError(name_, "no channel '" + c + "' (the device has: " + all + ")");
    if (!analog_mode()) {
        // Bit of each named channel in the unit of the enabled prefix (command()).
        std::size_t hi = 0;
        for (const auto& c : cfg_.logic_channels) {
            const auto idx = static_cast<std::size_t>(std::find(device_channels_.begin(), device_channels_.end(), c) - device_channels_.begin());
            logic_bit_.push_back(static_cast<int>(idx));
            hi = std::max(hi, idx);
        }
        if (hi >= 64) throw DeviceError(name_, "channel " + device_channels_[hi] + " is beyond the 64 bits fringe reads per sample");
        unitsize_ = hi / 8 + 1;
        // A replayed file's units are its own (every channel it holds, at its index).
        if (file_unitsize_) {
            if (hi / 8 + 1 > file_unitsize_) throw DeviceError(name_, "channel " + device_channels_[hi] + " is beyond the session's unit");
            unitsize_ = file_unitsize_;
        }
        identity_bits_ = true;
        for (std::size_t k = 0; k < logic_bit_.size(); ++k) identity_bits_ = identity_bits_ && logic_bit_[k] == static_cast<int>(k);
    } else {
        analog_q_.assign(cfg_.analog_channels.size(), {});
    }
    probed_ = true;
}

void SigrokLive::start() {
    if (started_) throw DeviceError(name_, "already started");
    probe();
    std::string error;
    t0_ = std::chrono::steady_clock::now();
    pid_ = spawn(command(), in_fd_, out_fd_, err_fd_, error);
    if (pid_ < 0) throw DeviceError(name_, error);
    started_ = true;
}

void SigrokLive::drain_stderr() {
    if (err_fd_ < 0) return;
    char b[4096];
    while (true) {
        const ssize_t n = ::read(err_fd_, b, sizeof b);
        if (n > 0) {
            append_tail(stderr_tail_, b, static_cast<std::size_t>(n));
            continue;
        }
        if (n == 0 || (errno != EAGAIN && errno != EINTR)) {
            ::close(err_fd_);
            err_fd_ = -1;
        }
        if (n < 0 && errno == EINTR) continue;
        return;
    }
}

bool SigrokLive::reap(int wait_ms) {
    if (reaped_ || pid_ < 0) return reaped_;
    const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(wait_ms);
    while (true) {
        int st = 0;
        const pid_t r = ::waitpid(pid_, &st, WNOHANG);
        if (r == pid_) {
            wait_status_ = st;
            reaped_ = true;
            t_end_ = std::chrono::steady_clock::now();
            return true;
        }
        if (r < 0 && errno != EINTR) {  // not our child any more (reaped elsewhere)
            reaped_ = true;
            t_end_ = std::chrono::steady_clock::now();
            wait_status_ = -1;
            return true;
        }
        if (std::chrono::steady_clock::now() >= until) return false;
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
}

std::string SigrokLive::exit_text() const {
    std::string s = "sigrok-cli (pid " + std::to_string(pid_) + ") " + (reaped_ ? (wait_status_ < 0 ? "was reaped elsewhere" : status_text(wait_status_)) : "still running");
    const std::string t = trimmed(stderr_tail_);
    if (!t.empty()) s += "; stderr: " + t;
    return s;
}

std::string SigrokLive::fail(const std::string& cause) {
    if (error_.empty()) error_ = cause;
    return error_;
}

bool SigrokLive::parse_stdout(std::string& error) {
    if (!analog_mode()) {
        const std::size_t units = buf_.size() / unitsize_;
        const auto* p = reinterpret_cast<const unsigned char*>(buf_.data());
        if (logic_head_ > 0 && logic_head_ >= logic_q_.size() / 2) {  // drop what was delivered
            logic_q_.erase(logic_q_.begin(), logic_q_.begin() + static_cast<std::ptrdiff_t>(logic_head_));
            logic_head_ = 0;
        }
        const std::size_t at = logic_q_.size();
        logic_q_.resize(at + units);
        std::uint64_t* dst = logic_q_.data() + at;
        const std::size_t nbits = logic_bit_.size();
        const std::uint64_t mask = nbits >= 64 ? ~0ull : (1ull << nbits) - 1;
        if (identity_bits_ && unitsize_ == 1) {
            for (std::size_t u = 0; u < units; ++u) dst[u] = p[u] & mask;
        } else {
            for (std::size_t u = 0; u < units; ++u, p += unitsize_) {
                std::uint64_t raw = 0;
                for (std::size_t b = 0; b < unitsize_; ++b) raw |= static_cast<std::uint64_t>(p[b]) << (8 * b);  // little-endian units
                if (identity_bits_) {
                    dst[u] = raw & mask;
                    continue;
                }
                std::uint64_t v = 0;
                for (std::size_t k = 0; k < nbits; ++k) v |= ((raw >> logic_bit_[k]) & 1u) << k;
                dst[u] = v;
            }
        }
        buf_.erase(0, units * unitsize_);
        received_ += units;
        return true;
    }
    std::size_t pos = 0;
    while (true) {
        const auto nl = buf_.find('\n', pos);
        if (nl == std::string::npos) break;
        const std::string line = buf_.substr(pos, nl - pos);
        pos = nl + 1;
        if (trimmed(line).empty()) continue;
        const auto colon = line.find(": ");
        std::size_t c = cfg_.analog_channels.size();
        if (colon != std::string::npos)
            c = static_cast<std::size_t>(std::find(cfg_.analog_channels.begin(), cfg_.analog_channels.end(), line.substr(0, colon)) - cfg_.analog_channels.begin());
        double v = 0;
        if (c == cfg_.analog_channels.size() || !parse_analog_value(line.substr(colon + 2), v)) {
            error = "unparsable sigrok-cli output line '" + line.substr(0, 80) + "'";
            buf_.erase(0, pos);
            return false;
        }
        analog_q_[c].push_back(v);
    }
    buf_.erase(0, pos);
    if (buf_.size() > 4096) {
        error = "sigrok-cli output line longer than 4096 bytes";
        return false;
    }
    std::size_t complete = SIZE_MAX;
    for (const auto& q : analog_q_) complete = std::min(complete, q.size());
    received_ = delivered_ + complete;
    return true;
}

std::size_t SigrokLive::frames_ready() const {
    if (!analog_mode()) return logic_q_.size() - logic_head_;
    std::size_t complete = SIZE_MAX;
    for (const auto& q : analog_q_) complete = std::min(complete, q.size());
    return complete;
}

StreamResult SigrokLive::read(std::size_t max, std::vector<std::uint64_t>& logic, std::vector<std::vector<double>>& analog, int timeout_ms) {
    logic.clear();
    analog.assign(cfg_.analog_channels.size(), {});
    StreamResult r;
    r.first_index = delivered_;
    if (!started_) {
        r.status = StreamStatus::Error;
        r.message = name_ + ": read before start()";
        return r;
    }
    if (stopped_ || max == 0) {
        r.status = StreamStatus::Error;
        r.message = name_ + (max == 0 ? ": read of 0 samples (0 frames with Ok is the end)" : ": read after stop()");
        return r;
    }
    const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(std::max(timeout_ms, 0));
    while (frames_ready() == 0 && error_.empty() && !ended_) {
        if (stdout_eof_) {
            // The stream ended: decide between the end and a failure from how the child ended.
            drain_stderr();
            if (!reap(2000)) {
                fail("sigrok-cli closed its output but did not exit: " + exit_text());
                break;
            }
            drain_stderr();
            const bool exited0 = reaped_ && wait_status_ >= 0 && WIFEXITED(wait_status_) && WEXITSTATUS(wait_status_) == 0;
            const bool analog_teardown = analog_mode() && reaped_ && wait_status_ >= 0 && WIFEXITED(wait_status_) && WEXITSTATUS(wait_status_) == 1 &&
                                         trimmed(stderr_tail_) == kAnalogTeardown && cfg_.limit_samples && received_ == cfg_.limit_samples;
            if (!buf_.empty()) {
                fail(std::to_string(buf_.size()) + " trailing bytes of an incomplete " + (analog_mode() ? "line" : "sample (unit of " + std::to_string(unitsize_) + " bytes)") +
                     " at the end; " + exit_text());
            } else if (analog_mode() && std::any_of(analog_q_.begin(), analog_q_.end(), [](const auto& q) { return !q.empty(); })) {
                fail("the channels ended with different sample counts; " + exit_text());
            } else if (!exited0 && !analog_teardown) {
                fail("acquisition ended after " + std::to_string(received_) + " samples: " + exit_text());
            } else if (!cfg_.limit_samples && !cfg_.input_file.empty()) {
                ended_ = true;  // a replayed session without a declared count: its end is the end
            } else if (!cfg_.limit_samples) {
                // Continuous: only stop() ends it; sigrok-cli ending by itself (a device gone,
                // a key it took for a stop) is not the end of the data.
                fail("the continuous acquisition ended by itself after " + std::to_string(received_) + " samples; " + exit_text());
            } else if (received_ != cfg_.limit_samples) {
                fail("acquisition ended after " + std::to_string(received_) + " of " + std::to_string(cfg_.limit_samples) + " samples; " + exit_text());
            } else {
                if (analog_teardown) exit_note_ = "sigrok-cli 0.7.2's analog teardown assertion (exit status 1) after all samples: accepted";
                ended_ = true;
            }
            break;
        }
        const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(until - std::chrono::steady_clock::now()).count();
        pollfd p[2] = {{out_fd_, POLLIN, 0}, {err_fd_, POLLIN, 0}};
        const int n = ::poll(p, 2, static_cast<int>(std::max<long long>(left, 0)));
        if (n < 0 && errno != EINTR) {
            fail(std::string("poll: ") + std::strerror(errno));
            break;
        }
        if (p[1].revents) drain_stderr();
        if (p[0].revents & (POLLIN | POLLHUP | POLLERR)) {
            char b[kReadChunk];
            while (true) {
                const ssize_t got = ::read(out_fd_, b, sizeof b);
                if (got > 0) {
                    if (!have_first_) {
                        t_first_ = std::chrono::steady_clock::now();
                        have_first_ = true;
                    }
                    buf_.append(b, static_cast<std::size_t>(got));
                    bytes_ += static_cast<std::uint64_t>(got);
                    if (buf_.size() >= (1u << 20)) break;
                    continue;
                }
                if (got == 0) stdout_eof_ = true;
                else if (errno == EINTR) continue;
                else if (errno != EAGAIN) fail(std::string("read: ") + std::strerror(errno));
                break;
            }
            std::string perr;
            if (!parse_stdout(perr)) {
                drain_stderr();
                fail(perr + "; " + exit_text());
            }
            if (cfg_.limit_samples && received_ > cfg_.limit_samples)
                fail("sigrok-cli delivered " + std::to_string(received_) + " samples, more than the " + std::to_string(cfg_.limit_samples) + " asked for");
        }
        if (frames_ready() == 0 && !stdout_eof_ && std::chrono::steady_clock::now() >= until) {
            r.status = StreamStatus::Timeout;
            r.message = name_ + ": no sample within " + std::to_string(timeout_ms) + " ms (" + std::to_string(delivered_) + " received so far; " + exit_text() + ")";
            return r;
        }
    }
    const std::size_t n = std::min(max, frames_ready());
    if (n > 0) {
        if (analog_mode()) {
            for (std::size_t c = 0; c < analog_q_.size(); ++c) {
                analog[c].assign(analog_q_[c].begin(), analog_q_[c].begin() + static_cast<std::ptrdiff_t>(n));
                analog_q_[c].erase(analog_q_[c].begin(), analog_q_[c].begin() + static_cast<std::ptrdiff_t>(n));
            }
        } else {
            const auto first = logic_q_.begin() + static_cast<std::ptrdiff_t>(logic_head_);
            logic.assign(first, first + static_cast<std::ptrdiff_t>(n));
            logic_head_ += n;
            if (logic_head_ == logic_q_.size()) {
                logic_q_.clear();
                logic_head_ = 0;
            }
        }
        delivered_ += n;
        r.frames = n;
        return r;  // frames before an error are delivered; the error comes with the next read
    }
    if (!error_.empty()) {
        r.status = StreamStatus::Error;
        r.message = name_ + ": " + error_;
    }
    return r;  // Ok, 0 frames: the end
}

void SigrokLive::stop() {
    if (pid_ > 0 && !reaped_) {
        t_end_ = std::chrono::steady_clock::now();
        wait_status_ = wait_or_kill(pid_, 0);
        reaped_ = true;
    }
    stopped_ = started_;
    drain_stderr();
    for (int* fd : {&in_fd_, &out_fd_, &err_fd_})
        if (*fd >= 0) {
            ::close(*fd);
            *fd = -1;
        }
}

nlohmann::json SigrokLive::stats() const {
    const auto now = started_ && reaped_ ? t_end_ : std::chrono::steady_clock::now();
    const double wall_s = started_ ? std::chrono::duration<double>(now - t0_).count() : 0.0;
    double expected = wall_s * cfg_.samplerate_hz;
    // From the first byte on: sigrok-cli's own start (process, scan of the driver, device open;
    // 50-80 ms for the demo) is not a loss.
    const double data_s = have_first_ ? std::chrono::duration<double>(now - t_first_).count() : 0.0;
    double expected_data = data_s * cfg_.samplerate_hz;
    if (cfg_.limit_samples) {
        expected = std::min(expected, static_cast<double>(cfg_.limit_samples));
        expected_data = std::min(expected_data, static_cast<double>(cfg_.limit_samples));
    }
    nlohmann::json j = {{"device", name_},
                        {"samples", delivered_},
                        {"samples_received", received_},
                        {"bytes", bytes_},
                        {"wall_s", wall_s},
                        {"expected_samples_by_wall_clock", std::floor(expected)},
                        {"first_data_s", have_first_ ? std::chrono::duration<double>(t_first_ - t0_).count() : -1.0},
                        {"data_wall_s", data_s},
                        {"expected_samples_since_first_data", std::floor(expected_data)},
                        {"samplerate_hz", cfg_.samplerate_hz},
                        {"limit_samples", cfg_.limit_samples},
                        {"logic_channels", cfg_.logic_channels},
                        {"analog_channels", cfg_.analog_channels},
                        {"format", analog_mode() ? "analog" : "binary"},
                        {"unitsize", unitsize_},
                        {"pid", pid_},
                        {"running", started_ && !reaped_},
                        {"stderr_tail", stderr_tail_},
                        {"drops", "not reported by sigrok-cli; compare samples with expected_samples_by_wall_clock for a device that samples in real time"}};
    if (!cfg_.input_file.empty()) {
        j["input_file"] = cfg_.input_file;
        j["drops"] = "a replayed session (sigrok-cli -i): read as fast as it comes, none dropped; samples against limit_samples, the count the file declares";
    }
    if (stopped_) j["stopped"] = true;
    if (reaped_ && wait_status_ >= 0) {
        j["exit"] = status_text(wait_status_);
        j["exit_status"] = WIFEXITED(wait_status_) ? WEXITSTATUS(wait_status_) : -1;
        j["exit_signal"] = WIFSIGNALED(wait_status_) ? WTERMSIG(wait_status_) : 0;
    }
    if (!exit_note_.empty()) j["exit_note"] = exit_note_;
    if (!error_.empty()) j["error"] = error_;
    return j;
}

// ---- The sigrok: device (instrument mode input) ---------------------------------------------
// sigrok:DRIVER?samplerate=HZ&sin=A0&cos=A1: a digitizer libsigrok drives, recording two analog
// channels as sin and cos through sigrok-cli (-O analog). Each record() runs one acquisition of
// exactly the samples asked for. It runs on its own clock (own_clock): the run aligns truth from
// the signals, as for the SCPI digitizers.
namespace {

class SigrokDevice : public Device, public RecordPort {
public:
    SigrokDevice(std::string uri, std::string driver, const nlohmann::json& s) : uri_(std::move(uri)), driver_(std::move(driver)) {
        rate_hz_ = s.value("samplerate", 0.0);
        sin_ = s.value("sin", std::string("A0"));
        cos_ = s.value("cos", std::string("A1"));
        // No program setting: a URI may come over HTTP (under the operator's --allow-device
        // glob), and must not name an executable to run. sigrok-cli is the one on PATH.
        program_ = "sigrok-cli";
        if (driver_.empty()) throw DeviceError(uri_, "sigrok needs a driver: sigrok:demo, sigrok:fx2lafw:conn=1.5 (sigrok-cli -d)");
        // The driver and the channels are checked now (sigrok-cli --scan), not at the first record.
        SigrokLive probe(config(rate_hz_ > 0 ? rate_hz_ : 1.0, 1));
        try {
            probe.probe();
        } catch (const DeviceError& e) {
            throw DeviceError(uri_, e.what());
        }
    }

    RecordPort* recorder() override { return this; }

    DeviceInfo describe() const override {
        DeviceInfo i;
        i.driver = "sigrok";
        i.uri = uri_;
        i.description = "sigrok device '" + driver_ + "' through sigrok-cli (-O analog): sin=" + sin_ + ", cos=" + cos_;
        i.board_id = "sigrok:" + driver_;
        i.own_clock = true;
        i.settings = {{"samplerate", rate_hz_}, {"sin", sin_}, {"cos", cos_}};
        if (!last_stats_.is_null()) i.settings["last_record"] = last_stats_;
        i.converter.known = false;
        i.converter.note = "sigrok-cli -O analog prints the digits the driver declares; converter noise not modelled";
        return i;
    }

    StreamResult record(std::span<double> s, std::span<double> c, double fs, double timeout_s) override {
        if (s.size() != c.size() || s.empty()) throw DeviceError(uri_, "record needs two channel buffers of equal, non-zero length");
        const double rate = rate_hz_ > 0 ? rate_hz_ : fs;
        SigrokLive live(config(rate, s.size()));
        live.start();
        const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
        std::vector<std::uint64_t> logic;
        std::vector<std::vector<double>> analog;
        StreamResult out;
        while (out.frames < s.size()) {
            const auto left_ms = std::chrono::duration_cast<std::chrono::milliseconds>(until - std::chrono::steady_clock::now()).count();
            if (left_ms <= 0) {
                out.status = StreamStatus::Timeout;
                out.message = uri_ + ": " + std::to_string(out.frames) + " of " + std::to_string(s.size()) + " samples within " + num(timeout_s) + " s";
                break;
            }
            auto r = live.read(s.size() - out.frames, logic, analog, static_cast<int>(std::min<long long>(left_ms, 1 << 30)));
            if (r.status != StreamStatus::Ok) {
                out.status = r.status;
                out.message = r.message;
                break;
            }
            if (r.frames == 0) {
                out.status = StreamStatus::Error;
                out.message = uri_ + ": the acquisition ended after " + std::to_string(out.frames) + " of " + std::to_string(s.size()) + " samples";
                break;
            }
            std::copy(analog[0].begin(), analog[0].end(), s.begin() + static_cast<std::ptrdiff_t>(out.frames));
            std::copy(analog[1].begin(), analog[1].end(), c.begin() + static_cast<std::ptrdiff_t>(out.frames));
            out.frames += r.frames;
        }
        live.stop();
        last_stats_ = live.stats();
        return out;
    }

private:
    SigrokLiveConfig config(double rate_hz, std::size_t n) const {
        SigrokLiveConfig c;
        c.driver = driver_;
        c.samplerate_hz = rate_hz;
        c.analog_channels = {sin_, cos_};
        c.limit_samples = n;
        c.program = program_;
        return c;
    }

    std::string uri_, driver_, sin_, cos_, program_;
    double rate_hz_ = 0;
    nlohmann::json last_stats_;
};

}  // namespace

void register_sigrok(std::vector<DriverInfo>& r) {
    DriverInfo d;
    d.scheme = "sigrok";
    d.summary = "A digitizer libsigrok drives, recorded live through sigrok-cli (docs/sigrok-live.md): sigrok:demo?samplerate=1000000&sin=A0&cos=A1, "
                "sigrok:DRIVER:conn=...; analog sin/cos channels, instrument mode (own clock)";
    d.settings = {
        {"samplerate", "Hz", ParamType::Number, 0.0, 0, 1e12, {}, "sample rate asked of the device (0: the run's)"},
        {"sin", "", ParamType::String, "A0", -kInf, kInf, {}, "the device's channel recorded as sin"},
        {"cos", "", ParamType::String, "A1", -kInf, kInf, {}, "the device's channel recorded as cos"},
    };
    d.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        return std::make_unique<SigrokDevice>(uri, path, s);
    };
    r.push_back(std::move(d));
}

}  // namespace fringe::dev
