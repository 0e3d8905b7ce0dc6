// readout: a DUT's own position, read out beside the run (a scenario's "device.dut";
// docs/dut-readouts.md "In a run"). The URI's path says where the words come from:
//   readout:/path/x.sr?protocol=ssi|biss|spi|abz&...   a logic capture (sigrok session) of the
//       DUT's lines, decoded by drivers/position_words.* (abz: drivers/abz.*)
//   readout:tcp://127.0.0.1:5000?protocol=lines&...    a line stream "<time> <count> [E]" from a
//       TCP socket (a board's own server, or a serial-to-TCP bridge)
//   readout:/path/file.txt?protocol=lines&...           the same lines from a file or a tty
//   readout:sigrok://DRIVER?protocol=..&logic_rate_hz=..  live from a logic analyser (sigrok-cli)
//   readout:sigrok:///path/x.sr?protocol=..             a recorded session replayed through that
//       same live path (sigrok-cli -i): what CI's replayed DUT stream uses
// Every word is time-stamped at its latch instant on the readout's clock; clock_offset_s maps
// that clock to the run's (t_run = t_readout + clock_offset_s).
#include "device.hpp"
#include "abz.hpp"
#include "position_words.hpp"
#include "sigrok_file.hpp"
#include "sigrok_live.hpp"

#include "signal_gen/base/config.hpp"

#include <arpa/inet.h>
#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fcntl.h>
#include <sys/stat.h>
#include <deque>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <variant>

namespace fringe::dev {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

double number_or(const nlohmann::json& s, const char* k, double d) { return s.contains(k) && s[k].is_number() ? s[k].get<double>() : d; }
std::string string_or(const nlohmann::json& s, const char* k, const std::string& d) { return s.contains(k) && s[k].is_string() ? s[k].get<std::string>() : d; }

// The protocol settings a URI may carry, by protocol (the rest of the query is the readout's own).
const std::map<std::string, std::vector<std::string>> kProtocolKeys = {
    {"ssi", {"position_bits", "code", "error_bits", "error_active_high", "timeout_s", "counts_per_rev", "cycles_per_rev", "offset_rad"}},
    {"biss", {"position_bits", "code", "max_ack_bits", "timeout_s", "counts_per_rev", "cycles_per_rev", "offset_rad"}},
    {"spi", {"mode", "word_bits", "msb_first", "position_bits", "position_shift", "error_bit", "error_active_high", "code", "counts_per_rev",
             "cycles_per_rev", "offset_rad"}},
    {"lines", {"time_unit", "sample_rate_hz", "position_bits", "max_line_bytes", "counts_per_rev", "cycles_per_rev", "offset_rad"}},
    {"abz", {"interpolation", "index_count", "offset_rad"}},
};
constexpr const char* kNeedZ =
    "; an ABZ readout needs its index line Z (z=CHANNEL): without it the count's A/B period, and so the DUT's absolute position, is "
    "unknown (a capture's a/b lines without Z are homed on the capture's truth instead: capture:x.sr?interpolation=N)";
const std::vector<std::string> kOwnKeys = {"protocol", "clock_offset_s", "word_rate_hz", "clk", "data", "cs", "a", "b", "z", "hold_s", "max_expanded_mb", "stall_s", "logic_rate_hz"};

// The protocol's settings from the query (numbers where the config wants them); a setting of
// another protocol is refused naming it.
nlohmann::json protocol_settings(const std::string& protocol, const nlohmann::json& s) {
    const auto& keys = kProtocolKeys.at(protocol);
    nlohmann::json out = nlohmann::json::object();
    for (const auto& [k, v] : s.items()) {
        if (v.is_null() || std::find(kOwnKeys.begin(), kOwnKeys.end(), k) != kOwnKeys.end()) continue;  // null: not given
        if (std::find(keys.begin(), keys.end(), k) == keys.end()) {
            std::string known;
            for (const auto& x : keys) known += (known.empty() ? "" : ", ") + x;
            throw ConfigError("device." + k, "not a setting of protocol " + protocol + " (its settings: " + known + ")");
        }
        out[k] = v;
    }
    return out;
}

// One source of words: decoders over a logic capture, or a parser over bytes.
class WordSource {
public:
    virtual ~WordSource() = default;
    // Appends words until one latched after up_to_s has been seen (kept for later) or the
    // source ends; returns the status of the underlying read.
    virtual StreamResult pull(double up_to_s, std::deque<PositionWord>& q, int timeout_ms) = 0;
    virtual nlohmann::json stats() const = 0;
    virtual void start() {}  // a live source starts acquiring
    virtual void stop() {}
    const std::atomic<bool>* cancel = nullptr;  // the run's cancel flag: a waiting source gives up
    bool cancelled() const { return cancel && cancel->load(); }
    // Why the source's end is a fault when the run needs words up to up_to_s ("" when it is not):
    // a live stream that stops more than slack_s before the run's time.
    virtual std::string end_fault(double up_to_s, double slack_s) const {
        (void)up_to_s, (void)slack_s;
        return "";
    }
};

// A sigrok session's logic lines through a decoder.
// A DUT's logic lines through a decoder: from a sigrok session file, or live from any device
// sigrok-cli drives (path sigrok://DRIVER, drivers/sigrok_live.hpp), sample k at t = k / rate.
class LogicSource final : public WordSource {
public:
    LogicSource(const std::string& uri, const std::string& path, const std::string& protocol, const nlohmann::json& s)
        : uri_(uri), hold_s_(number_or(s, "hold_s", 0.01)) {
        std::map<std::string, std::string> channel_for;
        auto line = [&](const char* col, const char* dflt) {
            const std::string ch = string_or(s, col, dflt);
            channel_for[col] = ch;
            names_[col] = ch;
        };
        const nlohmann::json ps = protocol_settings(protocol, s);
        try {
            if (protocol == "ssi") {
                line("clk", "clk"); line("data", "data");
                ssi_.emplace(ps.get<SsiConfig>());
            } else if (protocol == "biss") {
                line("clk", "ma"); line("data", "slo");
                biss_.emplace(ps.get<BissConfig>());
            } else if (protocol == "spi") {
                line("cs", "cs"); line("clk", "clk"); line("data", "data");
                spi_.emplace(ps.get<SpiConfig>());
            } else if (protocol == "abz") {
                // Z is required: without an index the count's A/B period, and so the DUT's
                // absolute position, is unknown to the readout (it has no truth to home on).
                line("a", "a"); line("b", "b"); line("z", "z");
                if (!ps.contains("interpolation")) throw ConfigError("device.interpolation", "an ABZ readout needs the DUT's interpolation factor N (A/B periods per electrical cycle)");
                AbzConfig c;
                c.interpolation = ps["interpolation"].get<int>();
                c.index_count = ps.value("index_count", 0LL);
                c.offset_rad = ps.value("offset_rad", 0.0);
                abz_.emplace(c);
                if (!(number_or(s, "word_rate_hz", 0) > 0))
                    throw ConfigError("device.word_rate_hz", "an ABZ readout is sampled: give the rate at which its count is read (word_rate_hz)");
            } else {
                throw ConfigError("device.protocol", "a logic capture (.sr) carries ssi, biss, spi or abz, not " + protocol);
            }
        } catch (const std::invalid_argument& e) {
            throw ConfigError("device", e.what());
        }
        if (abz_) abz_period_ = 1.0 / number_or(s, "word_rate_hz", 0);
        if (path.rfind("sigrok://", 0) == 0) {
            // Live: the lines in a fixed order, bit k of a sample = order_[k].
            SigrokLiveConfig c;
            const std::string what = path.substr(9);
            if (what.rfind('.', 0) == 0 || (what.size() > 3 && what.compare(what.size() - 3, 3, ".sr") == 0 && what[0] != '/'))
                throw ConfigError("device.path", "a recorded session is named by its absolute path: readout:sigrok:///abs/path/x.sr (got sigrok://" + what + ")");
            // sigrok:///abs/x.sr: a recorded session replayed through the same path (sigrok-cli -i).
            (what.rfind('/', 0) == 0 ? c.input_file : c.driver) = what;
            c.samplerate_hz = number_or(s, "logic_rate_hz", 0);
            if (c.input_file.empty() && !(c.samplerate_hz > 0))
                throw ConfigError("device.logic_rate_hz", "a live logic readout needs its sample rate (logic_rate_hz)");
            for (const auto& [col, ch] : channel_for) {
                order_.push_back(col);
                c.logic_channels.push_back(ch);
            }
            live_.emplace(c);
            try {
                live_->probe();  // a wrong driver, file or channel fails here, naming it
            } catch (const DeviceError& e) {
                const std::string what_failed = e.what();
                if (abz_ && what_failed.find("no channel '" + channel_for["z"] + "'") != std::string::npos) throw DeviceError(uri, what_failed + kNeedZ);
                throw;
            }
            fs_ = live_->samplerate_hz();
            return;
        }
        const auto max_bytes = static_cast<std::uint64_t>(std::min(number_or(s, "max_expanded_mb", 4096.0), 1.6e7) * 1048576.0);
        try {
            session_.emplace(path, channel_for, max_bytes);
        } catch (const std::exception& e) {
            const std::string what_failed = e.what();
            throw DeviceError(uri, what_failed + (abz_ && what_failed.find("column 'z'") != std::string::npos ? kNeedZ : ""));
        }
        for (const auto& [col, ch] : channel_for)
            if (!session_->has(col))
                throw DeviceError(uri, path + ": no logic channel '" + ch + "' (the " + col + " line; channels: " + channels() + ")" +
                                           (col == "z" ? std::string(kNeedZ) : std::string()));
        fs_ = session_->sample_rate_hz();
        if (!(fs_ > 0)) throw DeviceError(uri, path + ": the session has no samplerate");
    }
    void start() override {
        if (live_) live_->start();
    }
    void stop() override {
        if (live_) live_->stop();
    }
    StreamResult pull(double up_to_s, std::deque<PositionWord>& q, int timeout_ms) override {
        StreamResult r;
        if (live_) r = pull_live(up_to_s, timeout_ms);
        // A frame latched before up_to_s completes within hold_s after it.
        while (!live_ && !ended_ && decoded_to_s_ < up_to_s + hold_s_) {
            if (cancelled()) return {StreamStatus::Error, 0, 0, 0, "cancelled while decoding the logic capture"};
            const std::uint64_t left = session_->frames() - read_;
            if (left == 0) {
                finish();
                ended_ = true;
                break;
            }
            const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(65536, left));
            cols_.clear();
            try {
                session_->read(n, cols_);
            } catch (const std::exception& e) {
                r.status = StreamStatus::Error;
                r.message = e.what();
                return r;
            }
            t_.resize(n);
            for (std::size_t i = 0; i < n; ++i) t_[i] = static_cast<double>(read_ + i) / fs_;
            read_ += n;
            decoded_to_s_ = t_[n - 1];
            decode(n);
        }
        for (auto& w : words_) q.push_back(std::move(w));
        words_.clear();
        return r;
    }
    StreamResult pull_live(double up_to_s, int timeout_ms) {
        StreamResult r;
        while (!ended_ && decoded_to_s_ < up_to_s + hold_s_) {
            if (cancelled()) return {StreamStatus::Error, 0, 0, 0, "cancelled while waiting for the logic analyser"};
            r = live_->read(65536, logic_, analog_, timeout_ms);
            if (r.status != StreamStatus::Ok) return r;
            const std::size_t n = r.frames;
            if (n == 0) {  // the acquisition ended (a sample limit)
                finish();
                ended_ = true;
                break;
            }
            cols_.clear();
            for (std::size_t k = 0; k < order_.size(); ++k) {
                auto& v = cols_[order_[k]];
                v.resize(n);
                for (std::size_t i = 0; i < n; ++i) v[i] = static_cast<double>((logic_[i] >> k) & 1u);
            }
            t_.resize(n);
            for (std::size_t i = 0; i < n; ++i) t_[i] = static_cast<double>(read_ + i) / fs_;
            read_ += n;
            decoded_to_s_ = t_[n - 1];
            decode(n);
        }
        r = {};
        return r;
    }
    nlohmann::json stats() const override {
        nlohmann::json j;
        if (ssi_) j = ssi_->to_json();
        if (biss_) j = biss_->to_json();
        if (spi_) j = spi_->to_json();
        if (abz_) {
            j = {{"abz", abz_->to_json()}, {"words", abz_words_}};
        }
        j["lines"] = names_;
        j["logic_rate_hz"] = fs_;
        j["logic_samples"] = read_;
        if (live_) j["sigrok"] = live_->stats();
        return j;
    }

private:
    std::string channels() const {
        std::string c;
        for (const auto& x : session_->channel_list()) c += (c.empty() ? "" : ", ") + x;
        return c;
    }
    void decode(std::size_t n) {
        const auto col = [&](const char* c) { return cols_.at(c).data(); };
        if (ssi_) ssi_->process(n, t_.data(), col("clk"), col("data"), words_);
        if (biss_) biss_->process(n, t_.data(), col("clk"), col("data"), words_);
        if (spi_) spi_->process(n, t_.data(), col("cs"), col("clk"), col("data"), words_);
        if (abz_) {
            th_.resize(n);
            abz_->process(n, t_.data(), col("a"), col("b"), cols_.count("z") ? col("z") : nullptr, nullptr, th_.data());
            // The count is the DUT's answer at every instant: read it at word_rate_hz.
            for (std::size_t i = 0; i < n; ++i) {
                if (t_[i] + 1e-12 < next_abz_t_) continue;
                PositionWord w;
                w.t_s = t_[i];
                w.theta_rad = th_[i];
                w.valid = std::isfinite(th_[i]);
                if (!w.valid) w.error = "abz_no_position";
                words_.push_back(w);
                ++abz_words_;
                next_abz_t_ += abz_period_;
                if (next_abz_t_ <= t_[i]) next_abz_t_ = t_[i] + abz_period_;
            }
        }
    }
    void finish() {
        if (ssi_) ssi_->finish(words_);
        if (biss_) biss_->finish(words_);
        if (spi_) spi_->finish(words_);
    }
    std::string uri_;
    double hold_s_;
    std::optional<SigrokSession> session_;
    std::optional<SigrokLive> live_;
    std::vector<std::string> order_;
    std::vector<std::uint64_t> logic_;
    std::vector<std::vector<double>> analog_;
    std::map<std::string, std::string> names_;
    std::optional<SsiDecoder> ssi_;
    std::optional<BissDecoder> biss_;
    std::optional<SpiDecoder> spi_;
    std::optional<AbzDecoder> abz_;
    double fs_ = 0, decoded_to_s_ = -std::numeric_limits<double>::infinity();
    double abz_period_ = 0, next_abz_t_ = 0;
    std::uint64_t read_ = 0, abz_words_ = 0;
    bool ended_ = false;
    std::map<std::string, std::vector<double>> cols_;
    std::vector<double> t_, th_;
    std::vector<PositionWord> words_;
};

// A line stream from a file, a tty or a TCP socket.
class LineSource final : public WordSource {
public:
    LineSource(const std::string& uri, const std::string& path, const nlohmann::json& s) : uri_(uri) {
        try {
            parser_.emplace(protocol_settings("lines", s).get<StreamConfig>());
        } catch (const std::invalid_argument& e) {
            throw ConfigError("device", e.what());
        }
        if (path.rfind("tcp://", 0) == 0) {
            tcp_ = stream_ = true;
            connect_tcp(path.substr(6));
        } else {
            // Non-blocking: a FIFO nobody writes to must not hang the open; a tty or FIFO is
            // then read as a live stream (polled, with the stall timeout), a file to its end.
            fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY | O_NONBLOCK);
            if (fd_ < 0) throw DeviceError(uri, "cannot open " + path + ": " + std::strerror(errno));
            struct stat st {};
            if (::fstat(fd_, &st) != 0) throw DeviceError(uri, "cannot stat " + path + ": " + std::strerror(errno));
            if (S_ISDIR(st.st_mode)) {
                ::close(fd_);
                fd_ = -1;
                throw DeviceError(uri, path + " is a directory, not a position stream");
            }
            stream_ = !S_ISREG(st.st_mode);
        }
    }
    ~LineSource() override {
        if (fd_ >= 0) ::close(fd_);
    }
    StreamResult pull(double up_to_s, std::deque<PositionWord>& q, int timeout_ms) override {
        StreamResult r;
        // stall: no word for timeout_ms (bytes that make no word, /dev/zero's, are silence too).
        auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
        std::uint64_t frames_seen = parser_->stats().frames;
        char buf[65536];
        while (!ended_ && !(have_last_ && last_t_ > up_to_s)) {
            // Bounded in time and memory whatever arrives; words pile up to at most 2^18 before
            // the run takes them.
            if (cancelled()) {
                r.status = StreamStatus::Error;
                r.message = "cancelled while waiting for the DUT's words";
                break;
            }
            if (parser_->stats().frames != frames_seen) {
                frames_seen = parser_->stats().frames;
                deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
            }
            if (std::chrono::steady_clock::now() >= deadline) {
                r.status = StreamStatus::Timeout;
                r.message = "no position word for " + std::to_string(timeout_ms) + " ms (stall_s; the stream had reached t = " +
                            (have_last_ ? std::to_string(last_t_) + " s" : std::string("no word yet")) + ", the run needs words up to " +
                            std::to_string(up_to_s) + " s; " + std::to_string(bytes_) + " bytes read)";
                break;
            }
            if (words_.size() >= (std::size_t{1} << 18)) break;
            if (stream_) {
                const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now()).count();
                pollfd p{fd_, POLLIN, 0};
                const int pr = ::poll(&p, 1, static_cast<int>(std::clamp<long long>(left, 0, 100)));  // 100 ms: a cancel is seen
                if (pr < 0 && errno == EINTR) continue;
                if (pr == 0) continue;  // the deadline and the cancel are checked above
            }
            const ssize_t got = ::read(fd_, buf, sizeof buf);
            if (got < 0) {
                if (errno == EINTR || errno == EAGAIN) continue;
                r.status = StreamStatus::Error;
                r.message = std::string("read: ") + std::strerror(errno);
                break;
            }
            if (got == 0) {
                parser_->finish(words_);
                ended_ = true;
                take_last();
                break;
            }
            bytes_ += static_cast<std::uint64_t>(got);
            parser_->feed(buf, static_cast<std::size_t>(got), words_);
            take_last();
        }
        for (auto& w : words_) q.push_back(std::move(w));
        words_.clear();
        return r;
    }
    std::string end_fault(double up_to_s, double slack_s) const override {
        if (!stream_ || !ended_ || (have_last_ && last_t_ >= up_to_s - slack_s)) return "";
        return std::string(tcp_ ? "the DUT closed the connection" : "the stream ended") + " (its stream reached t = " + (have_last_ ? std::to_string(last_t_) : std::string("nothing")) +
               " s; the run needs words up to " + std::to_string(up_to_s) + " s)";
    }
    nlohmann::json stats() const override {
        nlohmann::json j = parser_->to_json();
        j["bytes"] = bytes_;
        j["source"] = tcp_ ? "tcp" : stream_ ? "stream" : "file";
        return j;
    }

private:
    void take_last() {
        for (auto it = words_.rbegin(); it != words_.rend(); ++it)
            if (std::isfinite(it->t_s)) {
                have_last_ = true;
                last_t_ = std::max(last_t_, it->t_s);
                break;
            }
    }
    void connect_tcp(const std::string& hostport) {
        const auto colon = hostport.rfind(':');
        if (colon == std::string::npos) throw ConfigError("device", "a TCP readout needs tcp://host:port (got tcp://" + hostport + ")");
        std::string host = hostport.substr(0, colon);
        const std::string port = hostport.substr(colon + 1);
        if (host.size() > 1 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
        addrinfo hints{};
        hints.ai_socktype = SOCK_STREAM;
        addrinfo* res = nullptr;
        if (const int e = ::getaddrinfo(host.c_str(), port.c_str(), &hints, &res); e != 0)
            throw DeviceError(uri_, "cannot resolve " + hostport + ": " + ::gai_strerror(e));
        std::string why = "no address";
        for (addrinfo* a = res; a; a = a->ai_next) {
            const int fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
            if (fd < 0) continue;
            if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) {
                fd_ = fd;
                break;
            }
            why = std::strerror(errno);
            ::close(fd);
        }
        ::freeaddrinfo(res);
        if (fd_ < 0) throw DeviceError(uri_, "cannot connect to " + hostport + ": " + why);
    }
    std::string uri_;
    bool tcp_ = false, stream_ = false, ended_ = false, have_last_ = false;
    int fd_ = -1;
    double last_t_ = -std::numeric_limits<double>::infinity();
    std::uint64_t bytes_ = 0;
    std::optional<PositionStreamParser> parser_;
    std::vector<PositionWord> words_;
};

class Readout final : public Device, public ReadoutPort {
public:
    Readout(std::string uri, const std::string& path, const nlohmann::json& s)
        : uri_(std::move(uri)), path_(path), protocol_(string_or(s, "protocol", "")), offset_s_(number_or(s, "clock_offset_s", 0)),
          rate_hz_(number_or(s, "word_rate_hz", 0)), stall_s_(number_or(s, "stall_s", 10)), settings_(s) {
        const bool sr = path.size() >= 3 && path.compare(path.size() - 3, 3, ".sr") == 0;
        if (protocol_.empty()) protocol_ = sr || path.rfind("sigrok://", 0) == 0 ? "" : "lines";
        if (protocol_.empty()) throw ConfigError("device.protocol", "a logic capture needs protocol=ssi, biss, spi or abz");
        const bool live_logic = path.rfind("sigrok://", 0) == 0;
        if (live_logic && protocol_ == "lines") throw ConfigError("device.protocol", "a live logic readout (sigrok://) needs protocol=ssi, biss, spi or abz");
        if (sr || live_logic) src_ = std::make_unique<LogicSource>(uri_, path, protocol_, s);
        else if (protocol_ == "lines") src_ = std::make_unique<LineSource>(uri_, path, s);
        else throw ConfigError("device.protocol", protocol_ + " words are decoded from a logic capture (a .sr path); a file, tty or tcp:// stream carries protocol=lines");
    }
    ~Readout() override = default;
    ReadoutPort* readout() override { return this; }
    void set_cancel(const std::atomic<bool>* c) override { src_->cancel = c; }

    void start() override {
        src_->start();
        // ABZ words are the count read at word_rate_hz: nothing to measure.
        if (protocol_ == "abz") return;
        // The word rate from the first words (nominal: the median interval of up to 33); a rate
        // given must agree with it (it is the lane's sample rate: spectrum, settle, evidence).
        // At most the first 65.5 s of the readout's clock (a capture of silence is not decoded to
        // its end here: the run reads only up to its own time).
        for (double upto = 1e-3; q_.size() < 33 && upto < 100; upto *= 2) {  // the last: 65.5 s
            if (src_->cancelled()) throw DeviceError(uri_, "cancelled while reading the first words");
            const StreamResult r = src_->pull(upto, q_, static_cast<int>(stall_s_ * 1000));
            if (r.status != StreamStatus::Ok) throw DeviceError(uri_, std::string("reading the first words: ") + to_string(r.status) + ": " + r.message);
        }
        std::vector<double> dt;
        for (std::size_t i = 1; i < q_.size() && i < 33; ++i)
            if (q_[i].t_s > q_[i - 1].t_s) dt.push_back(q_[i].t_s - q_[i - 1].t_s);
        if (dt.size() < 2) {
            const nlohmann::json st = src_->stats();
            std::string seen;
            for (const char* k : {"lines", "frames", "valid_words", "malformed_lines", "time_reversals", "short_frames", "crc_errors", "samples", "logic_samples"})
                if (st.contains(k) && st[k].is_number()) seen += (seen.empty() ? "" : ", ") + std::string(k) + " " + st[k].dump();
            throw DeviceError(uri_, "fewer than three words with distinct latch times, so there is nothing to score and no word rate to measure (read: " +
                                        (seen.empty() ? std::string("nothing") : seen) + ")");
        }
        std::nth_element(dt.begin(), dt.begin() + static_cast<long>(dt.size() / 2), dt.end());
        const double measured_hz = 1.0 / dt[dt.size() / 2];
        if (rate_hz_ > 0) {
            if (std::abs(rate_hz_ - measured_hz) > 0.05 * measured_hz)
                throw DeviceError(uri_, "word_rate_hz=" + num(rate_hz_) + " but the first words come at " + num(measured_hz) +
                                            " Hz (the median of their first " + std::to_string(dt.size()) + " intervals): give the rate the DUT sends at, or leave it out to have it measured");
            return;
        }
        rate_hz_ = measured_hz;
        measured_rate_ = true;
    }
    StreamResult read_words(double up_to_s, std::vector<PositionWordOut>& out, int timeout_ms) override {
        StreamResult r;
        if (q_.empty() || q_.back().t_s <= up_to_s) r = src_->pull(up_to_s, q_, timeout_ms);
        // A live stream that has delivered its words to within two of the run's time and then
        // waits (the run's last block, a replay that holds its socket open) is not frozen.
        if (r.status == StreamStatus::Timeout && !q_.empty() && q_.back().t_s >= up_to_s - 2.0 / rate_hz_) r = {};
        // A live stream may end with the run (within two words of its last frame), not before.
        if (r.status == StreamStatus::Ok) {
            if (const std::string why = src_->end_fault(up_to_s, 2.0 / rate_hz_); !why.empty()) {
                r.status = StreamStatus::Error;
                r.message = why;
            }
        }
        std::size_t n = 0;
        while (!q_.empty() && (q_.front().t_s <= up_to_s || !std::isfinite(q_.front().t_s))) {
            const PositionWord& w = q_.front();
            out.push_back({w.t_s, w.valid ? w.theta_rad : kNaN, w.valid});
            q_.pop_front();
            ++n;
        }
        r.frames = n;
        return r;
    }
    double word_rate_hz() const override { return rate_hz_; }
    double readout_to_run_s() const override { return offset_s_; }
    double stall_s() const override { return stall_s_; }
    nlohmann::json stats() const override {
        nlohmann::json j = src_->stats();
        j["protocol"] = protocol_;
        j["word_rate_hz"] = rate_hz_;
        j["word_rate_measured"] = measured_rate_;
        return j;
    }
    void stop() override { src_->stop(); }

protected:
    DeviceInfo describe() const override {
        DeviceInfo i;
        i.driver = "readout";
        i.uri = uri_;
        i.description = protocol_ + " readout of a DUT from " + path_;
        i.board_id = "dut";
        i.settings = settings_;
        i.settings["path"] = path_;
        i.settings["protocol"] = protocol_;
        return i;
    }

private:
    std::string uri_, path_, protocol_;
    double offset_s_, rate_hz_, stall_s_;
    bool measured_rate_ = false;
    nlohmann::json settings_;
    std::unique_ptr<WordSource> src_;
    std::deque<PositionWord> q_;
};

}  // namespace

void register_readout(std::vector<DriverInfo>& r) {
    DriverInfo d;
    d.scheme = "readout";
    d.summary = "A DUT's own position words for a scenario's device.dut: a logic capture (.sr) or a live logic analyser (sigrok://DRIVER, "
                "through sigrok-cli; sigrok:///x.sr replays a session through it) decoded as SSI, BiSS-C, SPI or ABZ, or a line stream \"<time> <count> [E]\" from a file, a tty or tcp://host:port (docs/dut-readouts.md)";
    using P = ParamInfo;
    d.settings = {
        P{"protocol", "", ParamType::Choice, nullptr, -kInf, kInf, {"ssi", "biss", "spi", "abz", "lines"}, "the DUT's protocol (default: lines for a file, a tty or tcp://; a .sr or sigrok:// needs one)"},
        P{"clock_offset_s", "s", ParamType::Number, 0.0, -1e6, 1e6, {}, "t_run = t_readout + clock_offset_s (the readout's clock against the run's)"},
        P{"word_rate_hz", "Hz", ParamType::Number, nullptr, 0, 1e9, {}, "words per second (default: measured from the first words; abz: the rate its count is read)"},
        P{"logic_rate_hz", "Hz", ParamType::Number, nullptr, 0, 1e10, {}, "sigrok://DRIVER: the logic analyser's sample rate; sigrok:///x.sr: the file's own when absent (given, it must match)"},
        P{"hold_s", "s", ParamType::Number, 0.01, 0, 10, {}, "logic captures: a frame completes within this time after its latch"},
        P{"stall_s", "s", ParamType::Number, 10.0, 0.01, 3600, {}, "a live stream silent this long while the run waits for its words is frozen: the run ends with an error"},
        P{"max_expanded_mb", "MiB", ParamType::Number, 4096.0, 1, 1.6e7, {}, "most sample data a .sr may expand to (a limit against ZIP bombs)"},
        P{"clk", "", ParamType::String, nullptr, -kInf, kInf, {}, "logic channel of the clock (default: clk for SSI and SPI, ma for BiSS-C)"},
        P{"data", "", ParamType::String, nullptr, -kInf, kInf, {}, "logic channel of the data (default: data for SSI and SPI, slo for BiSS-C)"},
        P{"cs", "", ParamType::String, nullptr, -kInf, kInf, {}, "logic channel of SPI's chip select (default cs)"},
        P{"a", "", ParamType::String, nullptr, -kInf, kInf, {}, "ABZ: logic channel of A (default a)"},
        P{"b", "", ParamType::String, nullptr, -kInf, kInf, {}, "ABZ: logic channel of B (default b)"},
        P{"z", "", ParamType::String, nullptr, -kInf, kInf, {}, "ABZ: logic channel of the index Z (default: none, and the position is homed on truth at the first sample)"},
        P{"position_bits", "", ParamType::Integer, nullptr, 1, 64, {}, "bits of the position field (required for ssi and biss; spi: word_bits - position_shift; lines: 32, used when counts_per_rev is 0)"},
        P{"code", "", ParamType::Choice, nullptr, -kInf, kInf, {"binary", "gray"}, "position coding (default binary)"},
        P{"error_bits", "", ParamType::Integer, nullptr, 0, 8, {}, "SSI: status bits after the position (default 0)"},
        P{"error_active_high", "", ParamType::Boolean, nullptr, -kInf, kInf, {}, "SSI, SPI: an error bit at this level flags an error (default true)"},
        P{"timeout_s", "s", ParamType::Number, nullptr, 0, 1, {}, "SSI, BiSS: the clock idle this long ends a frame (default 2e-05)"},
        P{"max_ack_bits", "", ParamType::Integer, nullptr, 1, 1e6, {}, "BiSS: clock periods before the start bit, at most (default 32)"},
        P{"mode", "", ParamType::Integer, nullptr, 0, 3, {}, "SPI mode (2*CPOL + CPHA; default 0)"},
        P{"word_bits", "", ParamType::Integer, nullptr, 1, 64, {}, "SPI: bits per CS frame (required)"},
        P{"msb_first", "", ParamType::Boolean, nullptr, -kInf, kInf, {}, "SPI bit order (default true)"},
        P{"position_shift", "", ParamType::Integer, nullptr, 0, 63, {}, "SPI: position field's lowest bit in the word (default 0)"},
        P{"error_bit", "", ParamType::Integer, nullptr, -1, 63, {}, "SPI: error flag bit in the word (-1, the default: none)"},
        P{"counts_per_rev", "", ParamType::Integer, nullptr, 0, 9e15, {}, "word values per revolution (default 2^position_bits)"},
        P{"cycles_per_rev", "", ParamType::Integer, nullptr, 1, 1e9, {}, "electrical cycles per revolution of the word (default 1)"},
        P{"offset_rad", "rad", ParamType::Number, nullptr, -1e3, 1e3, {}, "electrical angle of value 0's lower edge (abz: of count 0; default 0)"},
        P{"time_unit", "", ParamType::Choice, nullptr, -kInf, kInf, {"s", "sample"}, "lines: the time field in seconds or as a sample index (default s)"},
        P{"sample_rate_hz", "Hz", ParamType::Number, nullptr, 0, 1e12, {}, "lines: the sample rate of time_unit=sample"},
        P{"max_line_bytes", "bytes", ParamType::Integer, nullptr, 8, 65536, {}, "lines: a longer line is malformed (default 256)"},
        P{"interpolation", "", ParamType::Integer, nullptr, 1, 1000000, {}, "ABZ: A/B periods per electrical cycle (4N counts; required)"},
        P{"index_count", "", ParamType::Integer, nullptr, -1e9, 1e9, {}, "ABZ: the count at the Z index, mod 4N (default 0)"},
    };
    d.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        if (path.empty()) throw ConfigError("device", "readout needs a source: readout:/path/x.sr?protocol=..., readout:/path/lines.txt or readout:tcp://127.0.0.1:PORT");
        return std::make_unique<Readout>(uri, path, s);
    };
    r.push_back(std::move(d));
}

}  // namespace fringe::dev
