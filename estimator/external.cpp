// external: runs a user's estimator as a child process (docs/external-estimator.md).
// Samples go to its stdin, estimates come back on its stdout, one output frame per input
// frame and in order. Both pipes are non-blocking and served by one poll() loop, so a child
// that answers only after reading a whole block cannot deadlock us; a child that exits or
// stays silent for timeout_s ends the run with an EstimatorError that says so.
#include "common.hpp"
#include "correction.hpp"
#include "registry_parts.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>

namespace fringe::est {

namespace {

class External final : public Estimator {
public:
    static std::vector<ParamInfo> params() {
        return {
            {"command", "", ParamType::String, nullptr, -kInf, kInf, {}, "shell command that starts the estimator (run by /bin/sh -c)"},
            {"protocol", "", ParamType::Choice, "text", -kInf, kInf, {"text", "binary"},
             "text: lines 'sin cos' in, 'theta_rad omega_rad_s valid' out; binary: little-endian f64 pairs in, f64 triples out"},
            {"timeout_s", "s", ParamType::Number, 10.0, 0.01, 3600, {}, "give up when the child makes no progress for this long"},
            {"model", "", ParamType::Choice, "unknown", -kInf, kInf, {"unknown", "memoryless", "tracker-cv", "tracker-ca"},
             "what the child is, so it is graded like a built-in estimator: memoryless (per-sample CRB), a tracker with a "
             "constant-velocity or constant-acceleration prior (PCRB at natural_freq_hz); unknown: no efficiency"},
            {"natural_freq_hz", "Hz", ParamType::Number, 0.0, 0.0, 1e7, {}, "a tracker's loop natural frequency (its declared prior; required for tracker-cv/-ca)"},
            {"correction", "", ParamType::String, nullptr, -kInf, kInf, {},
             "correction file (fringe calibrate -o; docs/calibration.md), checked, then handed to the child as FRINGE_CORRECTION (its absolute path): the child applies it itself"},
        };
    }
    ~External() override { stop(); }

    void reset(const EstimatorConfig& cfg) override {
        stop();
        const Params p = resolve_params(params(), cfg.params);
        command_ = p.string("command");
        if (command_.empty()) throw ConfigError("params.command", "is required (the command that runs your estimator)");
        binary_ = p.string("protocol") == "binary";
        timeout_ms_ = static_cast<int>(p.number("timeout_s") * 1000);
        if (!(cfg.sample_rate_hz > 0)) throw ConfigError("sample_rate_hz", "must be positive");
        model_ = p.string("model");
        fn_hz_ = p.number("natural_freq_hz");
        if ((model_ == "tracker-cv" || model_ == "tracker-ca") && !(fn_hz_ > 0))
            throw ConfigError("params.natural_freq_hz", "a tracker's declared prior needs its natural frequency (> 0 Hz)");
        correction_path_.clear();
        if (p.json().contains("correction") && !p.json().at("correction").is_null()) {
            const std::string given = p.string("correction");
            try {
                (void)Correction::load(given);  // a malformed file fails here, naming the field, not in the child
            } catch (const ConfigError& e) {
                throw e.prefixed("params");
            }
            correction_path_ = std::filesystem::absolute(given).lexically_normal().string();
        }
        // The encoder and sampling as fringe knows them, for firmware configured like the
        // built-in estimators: a JSON file named by FRINGE_ENCODER_JSON.
        char tmpl[] = "/tmp/fringe-external-XXXXXX";
        const int fd = mkstemp(tmpl);
        if (fd < 0) throw EstimatorError(std::string("external: cannot write its configuration file: ") + std::strerror(errno));
        config_path_ = tmpl;
        nlohmann::json conf{{"schema", "fringe.external"}, {"schema_version", 1}, {"sample_rate_hz", cfg.sample_rate_hz},
                            {"protocol", binary_ ? "binary" : "text"},
                            {"phase_convention", "theta = 0 where sin = 0 and cos is at its maximum; theta increases with motion; unwrapped, in radians"},
                            {"encoder", cfg.encoder ? nlohmann::json(*cfg.encoder) : nlohmann::json()},
                            {"correction", correction_path_.empty() ? nlohmann::json() : nlohmann::json(correction_path_)}};
        const std::string text = conf.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
        const bool wrote = ::write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size());
        ::close(fd);
        if (!wrote) throw EstimatorError("external: cannot write its configuration file " + config_path_);
        // A child that dies while we write must give EPIPE, not kill the bench.
        ::signal(SIGPIPE, SIG_IGN);
        int in_pipe[2], out_pipe[2];
        if (pipe(in_pipe) != 0 || pipe(out_pipe) != 0) throw EstimatorError(std::string("external: pipe: ") + std::strerror(errno));
        const std::string rate = std::to_string(cfg.sample_rate_hz);
        const std::string proto = binary_ ? "binary" : "text";
        pid_ = fork();
        if (pid_ > 0) { setpgid(pid_, pid_); pgid_ = pid_; }  // also here: no race with the child's own call
        if (pid_ < 0) throw EstimatorError(std::string("external: fork: ") + std::strerror(errno));
        if (pid_ == 0) {
            setpgid(0, 0);  // its own process group, so stop() also ends anything it started
            dup2(in_pipe[0], 0);
            dup2(out_pipe[1], 1);
            close(in_pipe[0]); close(in_pipe[1]); close(out_pipe[0]); close(out_pipe[1]);
            setenv("FRINGE_SAMPLE_RATE_HZ", rate.c_str(), 1);
            setenv("FRINGE_PROTOCOL", proto.c_str(), 1);
            setenv("FRINGE_ENCODER_JSON", config_path_.c_str(), 1);
            if (correction_path_.empty()) unsetenv("FRINGE_CORRECTION");  // not one inherited from fringe's own environment
            else setenv("FRINGE_CORRECTION", correction_path_.c_str(), 1);
            signal(SIGPIPE, SIG_DFL);
            execl("/bin/sh", "sh", "-c", command_.c_str(), static_cast<char*>(nullptr));
            _exit(127);
        }
        close(in_pipe[0]);
        close(out_pipe[1]);
        to_child_ = in_pipe[1];
        from_child_ = out_pipe[0];
        fcntl(to_child_, F_SETFL, fcntl(to_child_, F_GETFL) | O_NONBLOCK);
        fcntl(from_child_, F_SETFL, fcntl(from_child_, F_GETFL) | O_NONBLOCK);
        fcntl(to_child_, F_SETFD, FD_CLOEXEC);
        fcntl(from_child_, F_SETFD, FD_CLOEXEC);
        samples_ = 0;
        partial_.clear();
    }

    void process(InputSpan in, OutputSpan out) override {
        if (pid_ <= 0) throw EstimatorError("external: the child process is not running (reset failed or it already ended)");
        const std::size_t n = in.size();
        std::string tx;
        if (binary_) {
            tx.resize(16 * n);
            for (std::size_t i = 0; i < n; ++i) {
                std::memcpy(&tx[16 * i], &in.sin_v[i], 8);
                std::memcpy(&tx[16 * i + 8], &in.cos_v[i], 8);
            }
        } else {
            tx.reserve(48 * n);
            char line[96];
            for (std::size_t i = 0; i < n; ++i) {
                const int len = std::snprintf(line, sizeof line, "%.17g %.17g\n", in.sin_v[i], in.cos_v[i]);
                tx.append(line, static_cast<std::size_t>(len));
            }
        }
        std::size_t sent = 0, got = 0;
        bool stopped_reading = false;
        got_ = 0;
        std::string rx = std::move(partial_);
        partial_.clear();
        char buf[65536];
        auto last_progress = std::chrono::steady_clock::now();
        auto consume = [&]() {  // parse complete frames from rx into out
            if (binary_) {
                while (got < n && rx.size() >= 24) {
                    double f[3];
                    std::memcpy(f, rx.data(), 24);
                    rx.erase(0, 24);
                    put(out, got++, f[0], f[1], f[2]);
                    got_ = got;
                }
            } else {
                std::size_t pos;
                while (got < n && (pos = rx.find('\n')) != std::string::npos) {
                    const std::string line = rx.substr(0, pos);
                    rx.erase(0, pos + 1);
                    double f[3];
                    char* end = nullptr;
                    const char* c = line.c_str();
                    for (int k = 0; k < 3; ++k) {
                        f[k] = std::strtod(c, &end);
                        if (end == c) fail("output line " + std::to_string(samples_ + got + 1) + " is not 'theta_rad omega_rad_s valid': '" + line + "'");
                        c = end;
                    }
                    put(out, got++, f[0], f[1], f[2]);
                    got_ = got;
                }
            }
        };
        while (got < n) {
            pollfd fds[2];
            int nf = 0;
            fds[nf++] = {from_child_, POLLIN, 0};
            if (sent < tx.size()) fds[nf++] = {to_child_, POLLOUT, 0};
            const int rc = poll(fds, static_cast<nfds_t>(nf), 100);
            if (rc < 0 && errno != EINTR) fail(std::string("poll: ") + std::strerror(errno));
            bool progress = false;
            if (nf == 2 && (fds[1].revents & (POLLOUT | POLLERR | POLLHUP))) {
                const ssize_t w = write(to_child_, tx.data() + sent, tx.size() - sent);
                if (w > 0) { sent += static_cast<std::size_t>(w); progress = true; }
                else if (w < 0 && errno != EAGAIN && errno != EINTR) {
                    // It stopped reading (probably exited): stop writing, but drain what it
                    // wrote before, so the report says how far it got.
                    sent = tx.size();
                    stopped_reading = true;
                }
            }
            if (fds[0].revents & (POLLIN | POLLHUP | POLLERR)) {
                const ssize_t r = read(from_child_, buf, sizeof buf);
                if (r > 0) { rx.append(buf, static_cast<std::size_t>(r)); progress = true; consume(); }
                else if (r == 0) fail_exited(std::string(stopped_reading ? "stopped reading its input and closed its output" : "closed its output") +
                                             " after " + std::to_string(samples_ + got) + " estimates for " + std::to_string(samples_ + n) +
                                             " samples (exactly one per input frame)");
                else if (errno != EAGAIN && errno != EINTR) fail(std::string("read: ") + std::strerror(errno));
            }
            const auto now = std::chrono::steady_clock::now();
            if (progress) last_progress = now;
            else if (now - last_progress > std::chrono::milliseconds(timeout_ms_)) {
                int status = 0;
                if (waitpid(pid_, &status, WNOHANG) == pid_) { pid_ = -1; fail(exit_text(status)); }
                fail("no output for " + std::to_string(timeout_ms_ / 1000.0).substr(0, 5) + " s with " + std::to_string(samples_ + got) +
                     " of " + std::to_string(samples_ + n) + " estimates received (one per input frame; does it flush its output after each line or block?)");
            }
        }
        samples_ += n;
        got_ = 0;
        // One estimate per input frame: a complete frame beyond them is an extra one (the child
        // cannot know samples it has not been sent).
        if (complete_frames(rx) > 0)
            fail("sent more estimates than samples: " + std::to_string(samples_ + complete_frames(rx)) + " estimates for " +
                 std::to_string(samples_) + " samples so far (exactly one per input frame)");
        partial_ = std::move(rx);  // a child may run ahead by at most a partial frame
    }

    void finish() override {
        if (pid_ <= 0) return;
        // Close its input; it must end its output with nothing more than the frames it owed.
        close(to_child_);
        to_child_ = -1;
        std::string rx = std::move(partial_);
        partial_.clear();
        char buf[4096];
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(std::min(timeout_ms_, 2000));
        for (;;) {
            pollfd fd{from_child_, POLLIN, 0};
            const int rc = poll(&fd, 1, 50);
            if (rc > 0) {
                const ssize_t r = read(from_child_, buf, sizeof buf);
                if (r > 0) { rx.append(buf, static_cast<std::size_t>(r)); continue; }
                if (r == 0) break;
                if (errno != EAGAIN && errno != EINTR) break;
            }
            if (std::chrono::steady_clock::now() > deadline) break;  // still running: stop() ends it
        }
        if (const std::size_t extra = complete_frames(rx))
            fail("sent more estimates than samples: " + std::to_string(samples_ + extra) + " estimates for " + std::to_string(samples_) +
                 " samples (exactly one per input frame)");
        if (!rx.empty() && !(rx.find_first_not_of(" \t\r\n") == std::string::npos && !binary_))
            fail("left a partial estimate (" + std::to_string(rx.size()) + " bytes) after its last full one");
        stop();
    }

    BoundClass bound_class() const override { return model_ == "memoryless" ? BoundClass::Memoryless : BoundClass::Tracker; }
    std::optional<TrackingPrior> prior() const override {
        if (model_ == "tracker-cv") return TrackingPrior{Kinematics::CV, fn_hz_};
        if (model_ == "tracker-ca") return TrackingPrior{Kinematics::CA, fn_hz_};
        return std::nullopt;
    }
    nlohmann::json state() const override { return {{"command", command_}, {"samples", samples_}, {"model", model_}}; }

private:
    std::size_t complete_frames(const std::string& rx) const {
        if (binary_) return rx.size() / 24;
        std::size_t n = 0;
        for (std::size_t pos = rx.find('\n'); pos != std::string::npos; pos = rx.find('\n', pos + 1)) ++n;
        return n;
    }
    void put(OutputSpan out, std::size_t i, double th, double om, double v) {
        if (!std::isfinite(th)) fail("estimate " + std::to_string(samples_ + i + 1) + " has a non-finite theta");
        if (v != 0.0 && !std::isfinite(om))
            fail("estimate " + std::to_string(samples_ + i + 1) + " is marked valid but its omega is not finite (mark it valid = 0, or give the rate)");
        out.theta_rad[i] = th;
        out.omega_rad_s[i] = om;
        out.valid[i] = v != 0.0 ? 1 : 0;
    }
    static std::string exit_text(int status) {
        if (WIFEXITED(status)) {
            const int code = WEXITSTATUS(status);
            std::string t = "exited with status " + std::to_string(code);
            // /bin/sh reports a child killed by signal N as 128 + N
            if (code > 128 && code < 128 + 32) t += std::string(" (killed by signal: ") + strsignal(code - 128) + ")";
            // /bin/sh's own codes for a command it could not run
            if (code == 127) t += " (the shell found no such command: check the path in 'command')";
            if (code == 126) t += " (the shell could not execute it: not executable, or not a program)";
            return t;
        }
        if (WIFSIGNALED(status)) return std::string("was killed by signal ") + strsignal(WTERMSIG(status));
        return "ended";
    }
    [[noreturn]] void fail_exited(const std::string& what) {
        // Give the child a moment to finish dying so we can say how it ended.
        int status = 0;
        for (int i = 0; i < 50; ++i) {
            if (waitpid(pid_, &status, WNOHANG) == pid_) {
                pid_ = -1;
                fail(what + "; it " + exit_text(status));
            }
            usleep(10000);
        }
        fail(what);
    }
    [[noreturn]] void fail(const std::string& what) {
        const std::string msg = "external estimator '" + command_ + "': " + what + " (after " +
                                std::to_string(samples_ + got_) + " estimates)";
        stop();
        throw EstimatorError(msg);
    }
    void stop() {
        if (to_child_ >= 0) { close(to_child_); to_child_ = -1; }
        if (pid_ > 0) {
            int status = 0;
            bool gone = false;
            for (int i = 0; i < 20 && !gone; ++i) {  // EOF on stdin should end it
                gone = waitpid(pid_, &status, WNOHANG) == pid_;
                if (!gone) usleep(5000);
            }
            if (!gone) { kill(-pid_, SIGKILL); waitpid(pid_, &status, 0); }
            pid_ = -1;
        }
        if (pgid_ > 0) { kill(-pgid_, SIGKILL); pgid_ = -1; }  // grandchildren (a wrapper script's helpers) too
        if (from_child_ >= 0) { close(from_child_); from_child_ = -1; }
        if (!config_path_.empty()) { ::unlink(config_path_.c_str()); config_path_.clear(); }
    }

    std::string command_, model_ = "unknown", config_path_, correction_path_;
    double fn_hz_ = 0;
    bool binary_ = false;
    int timeout_ms_ = 10000;
    pid_t pid_ = -1, pgid_ = -1;
    int to_child_ = -1, from_child_ = -1;
    std::uint64_t samples_ = 0;
    std::size_t got_ = 0;  // estimates received in the current block
    std::string partial_;
};

}  // namespace

void register_external(std::vector<EstimatorInfo>& r) {
    r.push_back({"external", "Your own estimator as a child process (e.g. host-compiled firmware): samples on stdin, estimates on stdout; see docs/external-estimator.md",
                 External::params(), [] { return std::make_unique<External>(); }});
    r.back().traits.child_process = true;
}

}  // namespace fringe::est
