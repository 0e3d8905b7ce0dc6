#include "drivers/sim/instrument_sim.hpp"

#include "drivers/scpi.hpp"
#include "signal_gen/base/constants.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <stdexcept>
#include <thread>
#include <vector>

namespace fringe::dev {

namespace {

constexpr std::size_t kMaxMessage = 600u << 20;  // a message (with its blocks) larger than this closes the connection

// ---- interpolation: Kaiser-windowed sinc, 16 taps each side, tabulated ----
constexpr int kHalf = 16;
constexpr int kRes = 512;  // table points per sample
double bessel_i0(double x) {
    double s = 1, t = 1;
    for (int k = 1; k < 40; ++k) {
        t *= (x / (2 * k)) * (x / (2 * k));
        s += t;
    }
    return s;
}
const std::vector<double>& kernel_table() {
    static const std::vector<double> t = [] {
        const double beta = 9.0;
        std::vector<double> v(kHalf * kRes + 2);
        for (std::size_t i = 0; i < v.size(); ++i) {
            const double x = static_cast<double>(i) / kRes;
            const double r = x / kHalf;
            const double w = r >= 1 ? 0 : bessel_i0(beta * std::sqrt(1 - r * r)) / bessel_i0(beta);
            v[i] = (x == 0 ? 1.0 : std::sin(kPi * x) / (kPi * x)) * w;
        }
        return v;
    }();
    return t;
}
double kernel(double x) {
    x = std::fabs(x);
    if (x >= kHalf) return 0;
    const double p = x * kRes;
    const auto i = static_cast<std::size_t>(p);
    const double f = p - static_cast<double>(i);
    const auto& t = kernel_table();
    return t[i] + (t[i + 1] - t[i]) * f;
}

// ---- SCPI header matching ----
struct Node {
    std::string name;
    int suffix = -1;  // -1: none given
};
// SCPI short form: the first four letters, three when the fourth is a vowel (IEEE 488.2 / SCPI 6.2.1).
std::string short_form(std::string s) {
    for (auto& ch : s) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
    if (s.size() <= 4) return s;
    const char c4 = s[3];
    return s.substr(0, (c4 == 'A' || c4 == 'E' || c4 == 'I' || c4 == 'O' || c4 == 'U') ? 3 : 4);
}
std::vector<Node> parse_header(std::string_view h) {
    std::vector<Node> out;
    if (!h.empty() && h.front() == ':') h.remove_prefix(1);
    while (!h.empty()) {
        const auto c = h.find(':');
        std::string part(h.substr(0, c));
        h = c == std::string_view::npos ? std::string_view() : h.substr(c + 1);
        Node n;
        std::size_t d = part.size();
        while (d > 0 && std::isdigit(static_cast<unsigned char>(part[d - 1]))) --d;
        if (d < part.size() && d > 0) n.suffix = std::atoi(part.c_str() + d);
        n.name = short_form(part.substr(0, d > 0 ? d : part.size()));
        out.push_back(n);
    }
    return out;
}
// Pattern "[SOUR#]:FUNC:ARB:SRAT": [..] optional, '#' a numeric suffix captured in *ch (-1 if
// absent). Nodes without '#' must carry the pattern's own suffix (DAC16) or none.
struct PatNode {
    std::string name;
    bool optional = false, capture = false;
    int suffix = -1;
};
std::vector<PatNode> parse_pattern(std::string_view p) {
    std::vector<PatNode> out;
    while (!p.empty()) {
        const auto c = p.find(':');
        std::string part(p.substr(0, c));
        p = c == std::string_view::npos ? std::string_view() : p.substr(c + 1);
        PatNode n;
        if (!part.empty() && part.front() == '[') {
            n.optional = true;
            part = part.substr(1, part.size() - 2);
        }
        if (!part.empty() && part.back() == '#') {
            n.capture = true;
            part.pop_back();
            n.name = part;
        } else {
            const auto nodes = parse_header(part);
            n.name = nodes.at(0).name;
            n.suffix = nodes.at(0).suffix;
        }
        out.push_back(n);
    }
    return out;
}
bool match_from(const std::vector<Node>& h, std::size_t i, const std::vector<PatNode>& p, std::size_t j, int* ch) {
    if (j == p.size()) return i == h.size();
    if (p[j].optional && match_from(h, i, p, j + 1, ch)) return true;
    if (i == h.size() || h[i].name != p[j].name) return false;
    if (p[j].capture) {
        if (ch) *ch = h[i].suffix;
    } else if (h[i].suffix != p[j].suffix) {
        return false;
    }
    return match_from(h, i + 1, p, j + 1, ch);
}

bool starts_with_ci(std::string_view s, std::string_view prefix) {
    if (prefix.empty() || s.size() < prefix.size()) return false;
    for (std::size_t i = 0; i < prefix.size(); ++i)
        if (std::toupper(static_cast<unsigned char>(s[i])) != std::toupper(static_cast<unsigned char>(prefix[i]))) return false;
    return true;
}

std::string upper(std::string s) {
    for (auto& ch : s) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
    return s;
}
std::string trim(std::string_view s) {
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
    return std::string(s);
}
// Leading whitespace only: a block's last data bytes may look like whitespace.
std::string ltrim(std::string_view s) {
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
    return std::string(s);
}
std::vector<std::string> split_commas(std::string_view s) {
    std::vector<std::string> v;
    std::size_t pos = 0;
    while (pos <= s.size()) {
        auto c = s.find(',', pos);
        if (c == std::string_view::npos) c = s.size();
        v.push_back(trim(s.substr(pos, c - pos)));
        pos = c + 1;
    }
    return v;
}
std::string fmt(double v) {
    char b[40];
    std::snprintf(b, sizeof b, "%.10g", v);
    return b;
}

struct SimError {
    int code;
    std::string text;
};
[[noreturn]] void err(int code, const std::string& text) { throw SimError{code, text}; }

double parse_number(const std::string& a) {
    const std::string s = trim(a);
    if (s.empty()) err(-109, "Missing parameter");
    char* end = nullptr;
    const double v = std::strtod(s.c_str(), &end);
    if (end == s.c_str() || *end != '\0' || !std::isfinite(v)) err(-104, "Data type error");
    return v;
}
bool parse_bool(const std::string& a) {
    const std::string u = upper(trim(a));
    if (u == "ON" || u == "1") return true;
    if (u == "OFF" || u == "0") return false;
    err(-224, "Illegal parameter value");
}

// ---- the instruments' state ----
using WallClock = std::chrono::steady_clock;

struct GenChannel {
    std::vector<double> norm;  // -1..1
    double rate_hz = 1e6, vpp = 0.1, offset_v = 0;
    double rp_freq_hz = 0;     // Red Pitaya: one pass of the buffer per 1/freq
    bool output = false, burst = false, infinite = true;
    std::string trig_source = "IMM";
    std::optional<double> start_s;  // when it started playing (sim seconds)
    double volts(std::size_t k) const { return offset_v + norm[k] * vpp / 2; }
};

struct Generator {
    std::string model;
    std::array<GenChannel, 2> ch;
    std::map<std::string, std::vector<double>> arbs;
    bool synced = false, little_endian = false;
    std::vector<std::uint16_t> rigol_pending[2];
    std::size_t memory = 0;
    double max_rate = 0, max_out_v = 10;
    int dac_bits = 16;
    void reset() {
        const auto m = model;
        const auto mem = memory;
        const auto r = max_rate;
        const auto mo = max_out_v;
        const int b = dac_bits;
        *this = Generator{};
        model = m, memory = mem, max_rate = r, max_out_v = mo, dac_bits = b;
    }
};

struct Digitizer {
    std::string kind;  // generic-scope | redpitaya
    double fs = 1e6;
    std::size_t points = 1000, pre = 0;
    std::string trig = "EXT";  // EXT | IMM (scope); NOW | AWG_PE | EXT_PE | DISABLED (Red Pitaya)
    enum class State { Stop, Wait, Run } state = State::Stop;
    std::optional<double> trig_s;  // when the record's sample `pre` was taken
    bool have = false;
    std::vector<double> data[2];   // volts at the digitizer's input
    // :WAV readout
    int wav_source = 1;
    std::string wav_format = "BYTE";
    bool wav_lsb = true;
    std::size_t wav_start = 1, wav_stop = 0;
    // Red Pitaya
    int dec = 1;
    long dly = 0;
    bool rp_started = false, rp_bin = false, rp_volts = true;
};

struct Port {
    int listen_fd = -1;
    int port = 0;
    bool gen = false, dig = false;
    std::string idn;
    std::deque<SimError> errors;
};

struct Client {
    int fd;
    Port* port;
    std::string in;
};

class Sim {
public:
    explicit Sim(const InstrumentSimOptions& o) : o_(o), rng_(o.seed) {
        epoch_ = WallClock::now();
        struct GenModel {
            const char* name;
            std::size_t memory;
            double rate;
            int bits;
            double max_out;
        };
        static const GenModel gm[] = {{"keysight-33500b", 1'000'000, 250e6, 16, 10}, {"keysight-33600a", 4'000'000, 1e9, 14, 10},
                                      {"rigol-dg800", 2'000'000, 200e6, 16, 10},     {"rigol-dg900", 8'000'000, 250e6, 16, 10},
                                      {"rigol-dg1000z", 8'000'000, 60e6, 14, 10},    {"siglent-sdg", 8'000'000, 300e6, 16, 10},
                                      {"redpitaya", 16384, 125e6, 14, 1}};
        const GenModel* g = nullptr;
        for (const auto& m : gm)
            if (o.generator == m.name) g = &m;
        if (!g) throw std::runtime_error("instrument-sim: unknown generator '" + o.generator + "' (known: " + instrument_sim_generators() + ")");
        if (o.digitizer != "generic-scope" && o.digitizer != "redpitaya")
            throw std::runtime_error("instrument-sim: unknown digitizer '" + o.digitizer + "' (known: " + instrument_sim_digitizers() + ")");
        gen_.model = g->name;
        gen_.memory = o.memory_samples ? o.memory_samples : g->memory;
        gen_.max_rate = g->rate;
        gen_.dac_bits = g->bits;
        gen_.max_out_v = g->max_out;
        dig_.kind = o.digitizer;
        const bool rp_pair = o.generator == "redpitaya" && o.digitizer == "redpitaya";
        ports_.push_back(std::make_unique<Port>());
        ports_[0]->gen = true;
        ports_[0]->dig = rp_pair;
        ports_[0]->port = o.generator_port;
        if (!o.fault.empty() && o.fault != "drop" && o.fault != "freeze" && o.fault != "truncate")
            throw std::runtime_error("instrument-sim: unknown fault '" + o.fault + "' (known: drop|freeze|truncate)");
        if (!o.fault.empty() && o.fault_on.empty()) throw std::runtime_error("instrument-sim: a fault needs the command it happens at (fault_on)");
        ports_[0]->idn = o.generator_idn.empty() ? idn_for(o.generator) : o.generator_idn;
        if (ports_[0]->idn.size() < o.idn_bytes) ports_[0]->idn.resize(o.idn_bytes, 'x');
        if (!rp_pair) {
            ports_.push_back(std::make_unique<Port>());
            ports_[1]->dig = true;
            ports_[1]->port = o.digitizer_port;
            ports_[1]->idn = o.digitizer_idn.empty() ? idn_for(o.digitizer) : o.digitizer_idn;
        }
        for (auto& p : ports_) listen(*p);
    }
    ~Sim() {
        for (auto& c : clients_) ::close(c.fd);
        for (auto& p : ports_)
            if (p->listen_fd >= 0) ::close(p->listen_fd);
    }

    long long run() {
        const bool rp_pair = ports_.size() == 1;
        if (o_.on_listening) {
            o_.on_listening("generator", uri(*ports_[0], o_.generator));
            o_.on_listening("digitizer", uri(rp_pair ? *ports_[0] : *ports_[1], o_.digitizer));
        }
        for (;;) {
            if (o_.stop && o_.stop->load()) break;
            if (o_.exit_after_s > 0 && now_s() >= o_.exit_after_s) break;
            std::vector<pollfd> pf;
            for (auto& p : ports_) pf.push_back({p->listen_fd, POLLIN, 0});
            for (auto& c : clients_) pf.push_back({c.fd, POLLIN, 0});
            const int n = ::poll(pf.data(), pf.size(), 50);
            if (n < 0 && errno != EINTR) throw std::runtime_error(std::string("instrument-sim: poll: ") + std::strerror(errno));
            if (n <= 0) continue;
            for (std::size_t i = 0; i < ports_.size(); ++i)
                if (pf[i].revents & POLLIN) {
                    const int fd = ::accept4(ports_[i]->listen_fd, nullptr, nullptr, SOCK_CLOEXEC);
                    if (fd >= 0) {
                        int one = 1;
                        setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
                        clients_.push_back({fd, ports_[i].get(), {}});
                    }
                }
            std::vector<int> closed;
            const std::size_t nc = pf.size() - ports_.size();
            for (std::size_t k = 0; k < nc; ++k) {
                if (!(pf[ports_.size() + k].revents & (POLLIN | POLLHUP | POLLERR))) continue;
                Client& c = clients_[k];
                char buf[65536];
                const ssize_t r = ::recv(c.fd, buf, sizeof buf, 0);
                if (r <= 0) {
                    closed.push_back(c.fd);
                    continue;
                }
                c.in.append(buf, static_cast<std::size_t>(r));
                if (!serve(c)) closed.push_back(c.fd);
                if (dropped_) return answered_;
            }
            for (int fd : closed) {
                ::close(fd);
                clients_.erase(std::remove_if(clients_.begin(), clients_.end(), [&](const Client& c) { return c.fd == fd; }), clients_.end());
            }
        }
        return answered_;
    }

private:
    static std::string idn_for(const std::string& model) {
        if (model == "keysight-33500b") return "Keysight Technologies,33522B,MY00000001,4.00-3.15-2.00-58-00";
        if (model == "keysight-33600a") return "Keysight Technologies,33622A,MY00000002,A.02.03-3.15-03.64-00.01";
        if (model == "rigol-dg800") return "Rigol Technologies,DG822,DG8A000000001,00.02.05";
        if (model == "rigol-dg900") return "Rigol Technologies,DG952,DG9A000000001,00.02.05";
        if (model == "rigol-dg1000z") return "Rigol Technologies,DG1062Z,DG1ZA000000001,03.01.12";
        if (model == "siglent-sdg") return "Siglent Technologies,SDG2042X,SDG2XSIM000001,2.01.01.35R3";
        if (model == "redpitaya") return "REDPITAYA,INSTR2020,0,01-02";
        return "FRINGE,SIM-DIGITIZER,0,1.0";
    }
    std::string uri(const Port& p, const std::string& model) const {
        return "scpi+tcp://" + o_.host + ":" + std::to_string(p.port) + "?model=" + model;
    }
    void listen(Port& p) {
        const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        int one = 1;
        setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(static_cast<std::uint16_t>(p.port));
        if (inet_pton(AF_INET, o_.host.c_str(), &a.sin_addr) != 1) {
            ::close(fd);
            throw std::runtime_error("instrument-sim: '" + o_.host + "' is not an IPv4 address");
        }
        if (::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || ::listen(fd, 8) != 0) {
            const std::string e = std::strerror(errno);
            ::close(fd);
            throw std::runtime_error("instrument-sim: cannot listen on " + o_.host + ":" + std::to_string(p.port) + ": " + e);
        }
        socklen_t len = sizeof a;
        getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
        p.port = ntohs(a.sin_port);
        p.listen_fd = fd;
    }
    double now_s() const { return std::chrono::duration<double>(WallClock::now() - epoch_).count(); }

    // Splits complete messages off c.in (a newline outside blocks ends one) and answers them.
    bool serve(Client& c) {
        for (;;) {
            std::vector<std::size_t> semis, block_ends;
            std::size_t end = 0;
            std::string bad;
            const int st = scan(c.in, end, semis, block_ends, bad);
            if (st == 0) {
                if (c.in.size() > kMaxMessage) return false;
                return true;
            }
            if (st < 0) {  // a malformed block: the rest of the input cannot be framed
                push_error(*c.port, {-160, "Block data error"});
                c.in.clear();
                return true;
            }
            const std::string msg = c.in.substr(0, end);
            c.in.erase(0, end + 1);
            std::size_t from = 0;
            semis.push_back(msg.size());
            std::string reply;
            bool cut = false;
            for (std::size_t s : semis) {
                const bool binary_tail = std::find(block_ends.begin(), block_ends.end(), s) != block_ends.end();
                const std::string_view raw = std::string_view(msg).substr(from, s - from);
                const std::string unit = binary_tail ? ltrim(raw) : trim(raw);
                from = s + 1;
                if (unit.empty()) continue;
                ++count_;
                if (o_.drop_after >= 0 && count_ > o_.drop_after) {
                    dropped_ = true;
                    return false;
                }
                const bool hit = !o_.fault.empty() && starts_with_ci(unit, o_.fault_on) && ++fault_seen_ == o_.fault_count;
                if (hit && o_.fault == "drop") {
                    dropped_ = true;
                    return false;
                }
                if (hit && o_.fault == "freeze") frozen_ = true;
                if (frozen_) continue;
                if (o_.silent_after >= 0 && count_ > o_.silent_after) continue;
                try {
                    if (auto r = execute(*c.port, unit)) reply += (reply.empty() ? "" : ";") + *r;
                } catch (const SimError& e) {
                    push_error(*c.port, e);
                }
                if (!o_.error_on.empty() && starts_with_ci(unit, o_.error_on)) push_error(*c.port, {-200, o_.error_text});
                if (hit && o_.fault == "truncate") cut = true;
                ++answered_;
            }
            if (!reply.empty() && o_.reply_delay_s > 0) std::this_thread::sleep_for(std::chrono::duration<double>(o_.reply_delay_s));
            if (!reply.empty()) {
                if (cut) {  // half of it, then nothing more
                    reply.resize(reply.size() / 2);
                    frozen_ = true;
                } else {
                    reply += "\n";
                }
                std::size_t off = 0;
                while (off < reply.size()) {
                    const ssize_t n = ::send(c.fd, reply.data() + off, reply.size() - off, MSG_NOSIGNAL);
                    if (n <= 0) return false;
                    off += static_cast<std::size_t>(n);
                }
            }
        }
    }
    // 1: a message ends at `end` (';' positions in semis); 0: need more; -1: a bad block header.
    static int scan(const std::string& b, std::size_t& end, std::vector<std::size_t>& semis, std::vector<std::size_t>& block_ends, std::string& bad) {
        bool quote = false;
        std::size_t i = 0;
        while (i < b.size()) {
            const char ch = b[i];
            if (quote) {
                if (ch == '"') quote = false;
                ++i;
                continue;
            }
            if (ch == '"') {
                quote = true;
                ++i;
                continue;
            }
            if (ch == '\n') {
                end = i;
                return 1;
            }
            if (ch == ';') semis.push_back(i);
            if (ch == '#' && i + 1 < b.size() && b[i + 1] >= '1' && b[i + 1] <= '9') {
                const auto h = scpi::parse_block_header(std::string_view(b).substr(i), kMaxMessage);
                if (h.status == scpi::BlockHeader::Status::NeedMore) return 0;
                if (h.status == scpi::BlockHeader::Status::Bad) {
                    bad = h.error;
                    return -1;
                }
                if (b.size() < i + h.header_bytes + h.data_bytes) return 0;
                i += h.header_bytes + h.data_bytes;
                block_ends.push_back(i);
                continue;
            }
            if (ch == ',' && b.compare(i + 1 > 8 ? i - 8 : 0, 9, "WAVEDATA,") == 0 && i >= 8) {
                // Siglent WVDT: raw bytes after WAVEDATA, whose count the command's LENGTH gives.
                const auto lp = b.rfind("LENGTH,", i);
                if (lp == std::string::npos) return -1;
                const std::size_t len = std::strtoull(b.c_str() + lp + 7, nullptr, 10);
                if (len > kMaxMessage) return -1;
                if (b.size() < i + 1 + len) return 0;
                i += 1 + len;
                block_ends.push_back(i);
                continue;
            }
            ++i;
        }
        return 0;
    }
    void push_error(Port& p, const SimError& e) {
        if (p.errors.size() >= 20) {
            p.errors.back() = {-350, "Queue overflow"};
            return;
        }
        p.errors.push_back(e);
    }

    // ---- command dispatch ----
    std::optional<std::string> execute(Port& p, const std::string& unit) {
        std::size_t sp = 0;
        while (sp < unit.size() && !std::isspace(static_cast<unsigned char>(unit[sp]))) ++sp;
        std::string head = unit.substr(0, sp);
        const std::string args = sp < unit.size() ? unit.substr(sp + 1) : "";
        const bool q = !head.empty() && head.back() == '?';
        if (q) head.pop_back();
        const std::string uh = upper(head);
        if (uh.size() > 1 && uh[0] == '*') {
            if (uh == "*IDN" && q) return p.idn;
            if (uh == "*OPC" && q) return std::string("1");
            if ((uh == "*OPC" || uh == "*WAI") && !q) return std::nullopt;
            if (uh == "*ESR" && q) return std::string("0");
            if (uh == "*CLS" && !q) {
                p.errors.clear();
                return std::nullopt;
            }
            if (uh == "*RST" && !q) {
                if (p.gen) gen_.reset();
                if (p.dig) {
                    const auto k = dig_.kind;
                    dig_ = Digitizer{};
                    dig_.kind = k;
                }
                return std::nullopt;
            }
            if (uh == "*TRG" && !q && p.gen) {
                trigger({true, true}, !gen_.synced);
                return std::nullopt;
            }
            err(-113, "Undefined header");
        }
        const auto h = parse_header(head);
        int ch = -1;
        auto is = [&](const char* pat) {
            ch = -1;
            return match_from(h, 0, parse_pattern(pat), 0, &ch);
        };
        if (is("SYST:ERR") || is("SYST:ERR:NEXT")) {
            if (!q) err(-113, "Undefined header");
            if (p.errors.empty()) return std::string("0,\"No error\"");
            const auto e = p.errors.front();
            p.errors.pop_front();
            return std::to_string(e.code) + ",\"" + e.text + "\"";
        }
        if (p.gen) {
            const std::string& m = gen_.model;
            std::optional<std::string> r;
            bool handled = false;
            if (m.rfind("keysight", 0) == 0) handled = keysight(h, q, args, r);
            else if (m.rfind("rigol", 0) == 0) handled = rigol(h, q, args, r);
            else if (m == "siglent-sdg") handled = siglent(h, q, args, r);
            else if (m == "redpitaya") handled = redpitaya_gen(h, q, args, r);
            if (handled) return r;
        }
        if (p.dig) {
            std::optional<std::string> r;
            if (dig_.kind == "generic-scope" ? scope(h, q, args, r) : redpitaya_acq(h, q, args, r)) return r;
        }
        err(-113, "Undefined header");
    }

    GenChannel& chan(int suffix) {
        if (suffix == -1) suffix = 1;
        if (suffix < 1 || suffix > 2) err(-114, "Header suffix out of range");
        return gen_.ch[static_cast<std::size_t>(suffix - 1)];
    }
    void check_levels(const GenChannel& c) {
        if (std::fabs(c.offset_v) + c.vpp / 2 > gen_.max_out_v + 1e-9) err(-221, "Settings conflict;amplitude and offset exceed the output range");
    }
    std::vector<double> codes_to_norm(const std::string& data, int bytes, bool little, bool is_signed, double full) {
        if (data.size() % static_cast<std::size_t>(bytes)) err(-160, "Block data error;odd byte count");
        const std::size_t n = data.size() / static_cast<std::size_t>(bytes);
        if (n < 2) err(-222, "Data out of range;at least 2 points");
        if (n > gen_.memory) err(-225, "Out of memory;" + std::to_string(n) + " points exceed " + std::to_string(gen_.memory));
        std::vector<double> v(n);
        for (std::size_t k = 0; k < n; ++k) {
            const auto b0 = static_cast<std::uint8_t>(data[2 * k]), b1 = static_cast<std::uint8_t>(data[2 * k + 1]);
            const std::uint16_t u = little ? static_cast<std::uint16_t>(b0 | (b1 << 8)) : static_cast<std::uint16_t>((b0 << 8) | b1);
            const double code = is_signed ? static_cast<double>(static_cast<std::int16_t>(u)) : static_cast<double>(u);
            const double x = is_signed ? code / full : code / full * 2 - 1;
            if (x < -1.0001 || x > 1.0001) err(-222, "Data out of range;DAC code " + fmt(code));
            v[k] = std::clamp(x, -1.0, 1.0);
        }
        return v;
    }
    static std::string block_arg(const std::string& a) {
        try {
            return scpi::decode_block(ltrim(a), kMaxMessage);
        } catch (const std::exception&) {
            err(-160, "Block data error");
        }
    }

    // The trigger that starts the armed channels (output on, data loaded) now; without channel
    // sync the second channel starts 1.5 of its samples late.
    void trigger(std::array<bool, 2> which, bool skew) {
        const double t = now_s();
        std::optional<double> first;
        for (int k = 0; k < 2; ++k) {
            auto& c = gen_.ch[static_cast<std::size_t>(k)];
            if (!which[static_cast<std::size_t>(k)] || !c.output || c.norm.empty()) continue;
            c.start_s = t + (k == 1 && skew ? 1.5 / rate(c) : 0.0);
            if (!first) first = t;
        }
        if (first) sync_out(*first);
    }
    // The generator's sync output, wired to the digitizer's trigger input.
    void sync_out(double t) {
        const bool waiting = dig_.state == Digitizer::State::Wait;
        const bool on_gen = dig_.kind == "generic-scope" ? dig_.trig == "EXT" : (dig_.trig == "AWG_PE" || dig_.trig == "EXT_PE");
        if (waiting && on_gen) {
            dig_.trig_s = t;
            dig_.state = Digitizer::State::Run;
        }
    }
    double rate(const GenChannel& c) const {
        if (gen_.model == "redpitaya") return c.rp_freq_hz * static_cast<double>(c.norm.size());
        return c.rate_hz;
    }
    // Output on in continuous (untriggered) mode starts playing at once.
    void output_changed(GenChannel& c) {
        if (!c.output) {
            c.start_s.reset();
            return;
        }
        const bool waits = c.burst && c.trig_source != "IMM";
        if (!waits && !c.start_s && !c.norm.empty()) {
            c.start_s = now_s();
            sync_out(*c.start_s);
        }
    }

    bool keysight(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
        int ch = -1;
        auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
        if (is("FORM:BORD")) {
            if (q) r = gen_.little_endian ? "SWAP" : "NORM";
            else {
                const auto u = upper(trim(a));
                if (u != "NORM" && u != "NORMAL" && u != "SWAP" && u != "SWAPPED") err(-224, "Illegal parameter value");
                gen_.little_endian = u.rfind("SWAP", 0) == 0;
            }
            return true;
        }
        if (is("[SOUR#]:DATA:VOL:CLE")) {
            gen_.arbs.clear();
            return true;
        }
        if (is("[SOUR#]:DATA:ARB:DAC") || is("[SOUR#]:DATA:ARB")) {
            const bool dac = h.back().name == "DAC";
            chan(ch);
            const auto comma = a.find(',');
            if (comma == std::string::npos) err(-109, "Missing parameter");
            const std::string name = upper(trim(a.substr(0, comma)));
            const std::string rest = ltrim(a.substr(comma + 1));
            std::vector<double> v;
            if (dac) {
                v = codes_to_norm(block_arg(rest), 2, gen_.little_endian, true, 32767);
            } else if (!rest.empty() && rest[0] == '#') {  // float32 block
                const std::string d = block_arg(rest);
                if (d.size() % 4) err(-160, "Block data error");
                for (std::size_t k = 0; k < d.size(); k += 4) {
                    std::uint8_t b[4];
                    for (int i = 0; i < 4; ++i) b[i] = static_cast<std::uint8_t>(d[k + static_cast<std::size_t>(gen_.little_endian ? i : 3 - i)]);
                    float f;
                    std::memcpy(&f, b, 4);
                    if (!(f >= -1.0001f && f <= 1.0001f)) err(-222, "Data out of range");
                    v.push_back(std::clamp(static_cast<double>(f), -1.0, 1.0));
                }
            } else {
                for (const auto& x : split_commas(rest)) {
                    const double f = parse_number(x);
                    if (f < -1 || f > 1) err(-222, "Data out of range");
                    v.push_back(f);
                }
            }
            if (v.size() < 8) err(-222, "Data out of range;at least 8 points");
            if (v.size() > gen_.memory) err(-225, "Out of memory");
            gen_.arbs[name] = std::move(v);
            return true;
        }
        if (is("[SOUR#]:DATA:ATTR:POIN") && q) {
            const auto it = gen_.arbs.find(upper(trim(a)));
            if (it == gen_.arbs.end()) err(-224, "Illegal parameter value;no such arb");
            r = std::to_string(it->second.size());
            return true;
        }
        if (is("[SOUR#]:DATA:ATTR:AVER") && q) {
            const auto it = gen_.arbs.find(upper(trim(a)));
            if (it == gen_.arbs.end()) err(-224, "Illegal parameter value;no such arb");
            double s = 0;
            for (double x : it->second) s += x;
            r = fmt(s / static_cast<double>(it->second.size()));
            return true;
        }
        if (is("[SOUR#]:FUNC:ARB:SRAT")) {
            auto& c = chan(ch);
            if (q) r = fmt(c.rate_hz);
            else {
                const double v = parse_number(a);
                if (v < 1e-6 || v > gen_.max_rate) err(-222, "Data out of range");
                c.rate_hz = v;
            }
            return true;
        }
        if (is("[SOUR#]:FUNC:ARB:SYNC")) {
            gen_.synced = true;
            return true;
        }
        if (is("[SOUR#]:FUNC:ARB")) {
            auto& c = chan(ch);
            const auto it = gen_.arbs.find(upper(trim(a)));
            if (it == gen_.arbs.end()) err(-224, "Illegal parameter value;no such arb waveform");
            c.norm = it->second;
            c.start_s.reset();
            return true;
        }
        if (is("[SOUR#]:FUNC")) {
            chan(ch);
            if (q) r = "ARB";
            return true;
        }
        if (is("[SOUR#]:VOLT:OFFS")) {
            auto& c = chan(ch);
            if (q) r = fmt(c.offset_v);
            else {
                const double old = c.offset_v;
                c.offset_v = parse_number(a);
                try {
                    check_levels(c);
                } catch (...) {
                    c.offset_v = old;
                    throw;
                }
            }
            return true;
        }
        if (is("[SOUR#]:VOLT")) {
            auto& c = chan(ch);
            if (q) r = fmt(c.vpp);
            else {
                const double old = c.vpp, v = parse_number(a);
                if (v < 1e-3) err(-222, "Data out of range");
                c.vpp = v;
                try {
                    check_levels(c);
                } catch (...) {
                    c.vpp = old;
                    throw;
                }
            }
            return true;
        }
        if (is("[SOUR#]:BURS:MODE")) {
            chan(ch);
            return true;
        }
        if (is("[SOUR#]:BURS:NCYC")) {
            auto& c = chan(ch);
            const auto u = upper(trim(a));
            if (u == "INF" || u == "INFINITY") c.infinite = true;
            else {
                const double n = parse_number(a);
                if (n != 1) err(-222, "Data out of range;the emulator plays 1 or INF cycles");
                c.infinite = false;
            }
            return true;
        }
        if (is("[SOUR#]:BURS:STAT")) {
            chan(ch).burst = parse_bool(a);
            return true;
        }
        if (is("TRIG#:SOUR")) {
            auto& c = chan(ch);
            c.trig_source = upper(trim(a));
            return true;
        }
        if (is("OUTP#")) {
            auto& c = chan(ch);
            if (q) r = c.output ? "1" : "0";
            else {
                c.output = parse_bool(a);
                output_changed(c);
            }
            return true;
        }
        if (is("ABOR")) return true;
        return false;
    }

    bool rigol(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
        int ch = -1;
        auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
        if (is("[SOUR#]:APPL:ARB") || is("[SOUR#]:FUNC:ARB:SRAT")) {
            auto& c = chan(ch);
            if (q) r = fmt(c.rate_hz);
            else {
                const double v = parse_number(split_commas(a).at(0));
                if (v < 1e-6 || v > gen_.max_rate) err(-222, "Data out of range");
                c.rate_hz = v;
            }
            return true;
        }
        if (is("[SOUR#]:TRAC:DATA:DAC16")) {
            const int k = ch == -1 ? 0 : ch - 1;
            chan(ch);
            const auto parts = a.find(',');
            const auto parts2 = parts == std::string::npos ? std::string::npos : a.find(',', parts + 1);
            if (parts2 == std::string::npos || upper(trim(a.substr(0, parts))) != "VOLATILE") err(-109, "Missing parameter");
            const std::string flag = upper(trim(a.substr(parts + 1, parts2 - parts - 1)));
            if (flag != "CON" && flag != "END") err(-224, "Illegal parameter value");
            const std::string d = block_arg(a.substr(parts2 + 1));
            if (d.size() % 2 || d.size() > 32768) err(-222, "Data out of range;a packet holds at most 16384 points");
            auto& pend = gen_.rigol_pending[k];
            const double full = gen_.dac_bits == 14 ? 16383.0 : 65535.0;
            for (std::size_t i = 0; i < d.size(); i += 2) {
                const auto u = static_cast<std::uint16_t>(static_cast<std::uint8_t>(d[i]) | (static_cast<std::uint8_t>(d[i + 1]) << 8));
                if (u > full) err(-222, "Data out of range;DAC code " + std::to_string(u));
                pend.push_back(u);
            }
            if (pend.size() > gen_.memory) {
                pend.clear();
                err(-225, "Out of memory");
            }
            if (flag == "END") {
                auto& c = gen_.ch[static_cast<std::size_t>(k)];
                c.norm.resize(pend.size());
                for (std::size_t i = 0; i < pend.size(); ++i) c.norm[i] = static_cast<double>(pend[i]) / full * 2 - 1;
                pend.clear();
                c.start_s.reset();
            }
            return true;
        }
        if (is("[SOUR#]:VOLT:OFFS") || is("[SOUR#]:VOLT")) {
            auto& c = chan(ch);
            const bool offs = h.back().name == "OFFS";
            double& field = offs ? c.offset_v : c.vpp;
            if (q) r = fmt(field);
            else {
                const double old = field;
                field = parse_number(a);
                try {
                    check_levels(c);
                } catch (...) {
                    field = old;
                    throw;
                }
            }
            return true;
        }
        if (is("[SOUR#]:BURS:STAT") || is("[SOUR#]:BURS")) {
            chan(ch).burst = parse_bool(a);
            return true;
        }
        if (is("[SOUR#]:BURS:MODE")) {
            const auto u = upper(trim(a));
            if (u != "TRIG" && u != "TRIGGERED" && u != "INF" && u != "INFINITY" && u != "GAT" && u != "GATED") err(-224, "Illegal parameter value");
            chan(ch).infinite = u.rfind("INF", 0) == 0;
            return true;
        }
        if (is("[SOUR#]:BURS:NCYC")) {
            auto& c = chan(ch);
            if (parse_number(a) != 1) err(-222, "Data out of range;the emulator plays 1 cycle or INF mode");
            (void)c;
            return true;
        }
        if (is("[SOUR#]:BURS:TRIG:SOUR")) {
            auto& c = chan(ch);
            const auto u = upper(trim(a));
            c.trig_source = u.rfind("MAN", 0) == 0 ? "BUS" : u;
            return true;
        }
        if (is("[SOUR#]:BURS:TRIG") || is("[SOUR#]:BURS:TRIG:IMM")) {
            std::array<bool, 2> w{ch != 2, ch == 2};
            trigger(w, false);
            return true;
        }
        if (is("[SOUR#]:PHAS:SYNC")) {
            gen_.synced = true;
            return true;
        }
        if (is("OUTP#") || is("OUTP#:STAT")) {
            auto& c = chan(ch);
            if (q) r = c.output ? "ON" : "OFF";
            else {
                c.output = parse_bool(a);
                output_changed(c);
            }
            return true;
        }
        return false;
    }

    bool siglent(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
        int ch = -1;
        auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
        // key,value pairs (WAVEDATA's raw bytes taken whole)
        auto pairs = [&](std::string_view s) {
            std::map<std::string, std::string> kv;
            while (!s.empty()) {
                const auto c1 = s.find(',');
                if (c1 == std::string_view::npos) {
                    kv[upper(trim(s))] = "";
                    break;
                }
                const std::string key = upper(trim(s.substr(0, c1)));
                s.remove_prefix(c1 + 1);
                if (key == "WAVEDATA") {
                    kv[key] = std::string(s);
                    break;
                }
                const auto c2 = s.find(',');
                kv[key] = trim(s.substr(0, c2));
                s = c2 == std::string_view::npos ? std::string_view() : s.substr(c2 + 1);
            }
            return kv;
        };
        if (is("MODE")) {
            gen_.synced = upper(trim(a)) == "PHASE-LOCKED";
            return true;
        }
        if (is("C#:WVDT")) {
            auto& c = chan(ch);
            auto kv = pairs(a);
            if (!kv.count("WVNM") || !kv.count("WAVEDATA") || !kv.count("LENGTH")) err(-109, "Missing parameter");
            const std::string& d = kv["WAVEDATA"];
            if (std::to_string(d.size()) != kv["LENGTH"]) err(-160, "Block data error;WAVEDATA length differs from LENGTH");
            gen_.arbs[kv["WVNM"]] = codes_to_norm(d, 2, true, true, 32767);
            if (kv.count("AMPL")) c.vpp = parse_number(kv["AMPL"]);
            if (kv.count("OFST")) c.offset_v = parse_number(kv["OFST"]);
            check_levels(c);
            return true;
        }
        if (is("C#:ARWV")) {
            auto& c = chan(ch);
            auto kv = pairs(a);
            const auto it = gen_.arbs.find(kv["NAME"]);
            if (it == gen_.arbs.end()) err(-224, "Illegal parameter value;no such waveform");
            c.norm = it->second;
            c.start_s.reset();
            return true;
        }
        if (is("C#:SRAT")) {
            auto& c = chan(ch);
            if (q) {
                r = "C" + std::to_string(ch) + ":SRATE MODE,TARB,VALUE," + fmt(c.rate_hz);
                return true;
            }
            auto kv = pairs(a);
            if (kv["MODE"] != "TARB") err(-224, "Illegal parameter value;the emulator plays TrueArb (MODE,TARB)");
            const double v = parse_number(kv["VALUE"]);
            if (v < 1e-6 || v > gen_.max_rate) err(-222, "Data out of range");
            c.rate_hz = v;
            return true;
        }
        if (is("C#:BSWV")) {
            auto& c = chan(ch);
            auto kv = pairs(a);
            const double ov = c.vpp, oo = c.offset_v;
            if (kv.count("AMP")) c.vpp = parse_number(kv["AMP"]);
            if (kv.count("OFST")) c.offset_v = parse_number(kv["OFST"]);
            try {
                check_levels(c);
            } catch (...) {
                c.vpp = ov, c.offset_v = oo;
                throw;
            }
            return true;
        }
        if (is("C#:BTWV")) {
            auto& c = chan(ch);
            if (upper(trim(a)) == "MTRIG") {
                trigger({ch != 2 || gen_.synced, ch == 2 || gen_.synced}, false);
                return true;
            }
            auto kv = pairs(a);
            if (kv.count("STATE")) c.burst = kv["STATE"] == "ON";
            if (kv.count("TRSR")) c.trig_source = kv["TRSR"] == "MAN" ? "BUS" : kv["TRSR"];
            if (kv.count("TIME")) {
                if (kv["TIME"] == "INF") c.infinite = true;
                else if (parse_number(kv["TIME"]) == 1) c.infinite = false;
                else err(-222, "Data out of range;the emulator plays 1 or INF cycles");
            }
            return true;
        }
        if (is("C#:OUTP")) {
            auto& c = chan(ch);
            if (q) r = std::string("C") + std::to_string(ch) + ":OUTP " + (c.output ? "ON" : "OFF");
            else {
                c.output = parse_bool(split_commas(a).at(0));
                output_changed(c);
            }
            return true;
        }
        return false;
    }

    bool redpitaya_gen(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
        int ch = -1;
        auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
        if (is("GEN:RST")) {
            gen_.reset();
            return true;
        }
        if (is("SOUR#:FUNC")) {
            chan(ch);
            if (q) r = "ARBITRARY";
            return true;
        }
        if (is("SOUR#:TRAC:DATA:DATA")) {
            auto& c = chan(ch);
            std::vector<double> v;
            for (const auto& x : split_commas(a)) {
                const double f = parse_number(x);
                if (f < -1 || f > 1) err(-222, "Data out of range");
                v.push_back(f);
            }
            if (v.size() > 16384) err(-222, "Data out of range;the buffer holds 16384 samples");
            if (v.size() < 2) err(-222, "Data out of range");
            c.norm = std::move(v);
            c.start_s.reset();
            return true;
        }
        if (is("SOUR#:FREQ:FIX")) {
            auto& c = chan(ch);
            if (q) r = fmt(c.rp_freq_hz);
            else {
                const double f = parse_number(a);
                if (f <= 0 || f > 62.5e6) err(-222, "Data out of range");
                c.rp_freq_hz = f;
            }
            return true;
        }
        if (is("SOUR#:VOLT:OFFS") || is("SOUR#:VOLT")) {
            auto& c = chan(ch);
            const bool offs = h.back().name == "OFFS";
            if (q) {
                r = fmt(offs ? c.offset_v : c.vpp / 2);
                return true;
            }
            const double ov = c.vpp, oo = c.offset_v, v = parse_number(a);
            if (offs) c.offset_v = v;
            else c.vpp = 2 * v;  // VOLT is the amplitude
            try {
                check_levels(c);
            } catch (...) {
                c.vpp = ov, c.offset_v = oo;
                throw;
            }
            return true;
        }
        if (is("SOUR#:BURS:STAT")) {
            auto& c = chan(ch);
            const auto u = upper(trim(a));
            if (u != "BURST" && u != "CONTINUOUS") err(-224, "Illegal parameter value");
            c.burst = u == "BURST";
            c.infinite = !c.burst;
            return true;
        }
        if (is("SOUR#:BURS:NCYC") || is("SOUR#:BURS:NOR")) {
            chan(ch);
            if (parse_number(a) != 1) err(-222, "Data out of range;the emulator plays one burst of one cycle");
            return true;
        }
        if (is("SOUR#:TRIG:SOUR")) {
            chan(ch).trig_source = upper(trim(a)) == "INT" ? "BUS" : upper(trim(a));
            return true;
        }
        if (is("SOUR#:TRIG:INT")) {  // SOUR:TRIG:INT: both channels at once
            trigger({ch != 2, ch == -1 || ch == 2}, false);
            return true;
        }
        if (is("OUTP#:STAT")) {
            if (q) {
                r = chan(ch).output ? "ON" : "OFF";
                return true;
            }
            const bool on = parse_bool(a);
            for (int k = 1; k <= 2; ++k)
                if (ch == -1 || ch == k) {
                    chan(k).output = on;
                    chan(k).burst = chan(k).burst || chan(k).trig_source == "BUS";  // an INT-triggered channel waits for SOUR:TRIG:INT
                    output_changed(chan(k));
                }
            return true;
        }
        return false;
    }

    // ---- the analog link: the record, sampled on the digitizer's clock ----
    void acquire_if_done() {
        if (dig_.state != Digitizer::State::Run || !dig_.trig_s) return;
        const double done_s = *dig_.trig_s + static_cast<double>(dig_.points - dig_.pre) / dig_.fs;
        if (now_s() < done_s) return;
        const double k = 1 + o_.clock_ppm * 1e-6;
        std::normal_distribution<double> noise(0.0, 1.0);
        const double a = o_.bandwidth_hz > 0 ? 1 - std::exp(-2 * kPi * o_.bandwidth_hz / dig_.fs) : 1.0;
        for (int c = 0; c < 2; ++c) {
            const auto& g = gen_.ch[static_cast<std::size_t>(c)];
            auto& out = dig_.data[c];
            out.assign(dig_.points, 0.0);
            std::vector<double> x;
            if (g.start_s && g.output) {
                x.resize(g.norm.size());
                for (std::size_t i = 0; i < x.size(); ++i) x[i] = g.volts(i);
            }
            const double fr = x.empty() ? 0 : rate(g);
            double y_f = 0;
            for (std::size_t m = 0; m < dig_.points; ++m) {
                const double t = *dig_.trig_s + (static_cast<double>(m) - static_cast<double>(dig_.pre)) / dig_.fs;  // sim seconds
                double v = 0;
                if (!x.empty()) {
                    const double u = (t - *g.start_s - o_.delay_s) * k * fr;  // generator sample position
                    v = sim_interpolate(x, g.infinite, u);
                }
                double y = o_.gain * v + o_.offset_v + (o_.noise_v > 0 ? o_.noise_v * noise(rng_) : 0.0);
                y_f = m == 0 ? y : y_f + a * (y - y_f);
                out[m] = y_f;
            }
        }
        dig_.have = true;
        dig_.state = Digitizer::State::Stop;
    }
    void arm(bool immediate) {
        dig_.have = false;
        dig_.trig_s.reset();
        dig_.state = Digitizer::State::Wait;
        if (immediate) {
            dig_.trig_s = now_s() + static_cast<double>(dig_.pre) / dig_.fs;
            dig_.state = Digitizer::State::Run;
        }
    }

    bool scope(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
        int ch = -1;
        auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
        acquire_if_done();
        if (is("STOP") || is("RUN")) {
            if (h[0].name == "STOP" && dig_.state != Digitizer::State::Stop) dig_.state = Digitizer::State::Stop;
            return true;
        }
        if (is("SING")) {
            if (dig_.points < 1 || dig_.pre > dig_.points) err(-221, "Settings conflict;trigger position beyond the record");
            arm(dig_.trig == "IMM");
            return true;
        }
        if (is("ACQ:SRAT")) {
            if (q) r = fmt(dig_.fs);
            else {
                const double v = parse_number(a);
                if (v < 1 || v > 10e9) err(-222, "Data out of range");
                dig_.fs = v;
            }
            return true;
        }
        if (is("ACQ:POIN")) {
            if (q) r = std::to_string(dig_.points);
            else {
                const double v = parse_number(a);
                if (v < 1 || v > 50e6 || v != std::floor(v)) err(-222, "Data out of range;1..50000000 points");
                dig_.points = static_cast<std::size_t>(v);
            }
            return true;
        }
        if (is("TRIG:SOUR")) {
            const auto u = upper(trim(a));
            if (q) r = dig_.trig;
            else if (u == "EXT" || u == "EXTERNAL") dig_.trig = "EXT";
            else if (u == "IMM" || u == "IMMEDIATE") dig_.trig = "IMM";
            else err(-224, "Illegal parameter value");
            return true;
        }
        if (is("TRIG:POS")) {
            if (q) r = std::to_string(dig_.pre);
            else {
                const double v = parse_number(a);
                if (v < 0 || v != std::floor(v) || v > 50e6) err(-222, "Data out of range");
                dig_.pre = static_cast<std::size_t>(v);
            }
            return true;
        }
        if (is("TRIG:STAT") && q) {
            r = dig_.state == Digitizer::State::Wait ? "WAIT" : dig_.state == Digitizer::State::Run ? "RUN" : "STOP";
            return true;
        }
        if (is("WAV:SOUR")) {
            const auto u = upper(trim(a));
            if (q) r = "CHAN" + std::to_string(dig_.wav_source);
            else if (u == "CHAN1" || u == "CHANNEL1") dig_.wav_source = 1;
            else if (u == "CHAN2" || u == "CHANNEL2") dig_.wav_source = 2;
            else err(-224, "Illegal parameter value");
            return true;
        }
        if (is("WAV:FORM")) {
            const auto u = upper(trim(a));
            if (q) r = dig_.wav_format;
            else if (u == "BYTE" || u == "WORD") dig_.wav_format = u;
            else err(-224, "Illegal parameter value");
            return true;
        }
        if (is("WAV:BYT")) {
            const auto u = upper(trim(a));
            if (q) r = dig_.wav_lsb ? "LSBF" : "MSBF";
            else if (u == "LSBF" || u == "MSBF") dig_.wav_lsb = u == "LSBF";
            else err(-224, "Illegal parameter value");
            return true;
        }
        if (is("WAV:MODE")) return true;
        if (is("WAV:STAR") || is("WAV:STOP")) {
            const bool start = h.back().name == "STAR";
            if (q) {
                r = std::to_string(start ? dig_.wav_start : (dig_.wav_stop ? dig_.wav_stop : dig_.points));
                return true;
            }
            const double v = parse_number(a);
            if (v < 1 || v != std::floor(v) || v > static_cast<double>(dig_.points)) err(-222, "Data out of range");
            (start ? dig_.wav_start : dig_.wav_stop) = static_cast<std::size_t>(v);
            return true;
        }
        const bool word = dig_.wav_format == "WORD";
        const double yinc = 2 * o_.digitizer_range_v / (word ? 65536.0 : 256.0), yref = word ? 32768 : 128;
        if (is("WAV:PRE") && q) {
            r = std::to_string(word ? 1 : 0) + ",2," + std::to_string(dig_.points) + ",1," + fmt(1 / dig_.fs) + "," +
                fmt(-static_cast<double>(dig_.pre) / dig_.fs) + ",0," + fmt(yinc) + ",0," + fmt(yref);
            return true;
        }
        if (is("WAV:DATA") && q) {
            if (!dig_.have) err(-230, "Data corrupt or stale;no completed acquisition");
            const std::size_t lo = dig_.wav_start, hi = dig_.wav_stop ? dig_.wav_stop : dig_.points;
            if (lo > hi) err(-221, "Settings conflict;:WAV:STAR after :WAV:STOP");
            std::string d;
            d.reserve((hi - lo + 1) * (word ? 2 : 1));
            const double full = word ? 65535 : 255;
            for (std::size_t m = lo - 1; m < hi; ++m) {
                const double code = std::clamp(std::round(dig_.data[dig_.wav_source - 1][m] / yinc) + yref, 0.0, full);
                const auto u = static_cast<std::uint16_t>(code);
                if (word) {
                    d += static_cast<char>(dig_.wav_lsb ? (u & 0xFF) : (u >> 8));
                    d += static_cast<char>(dig_.wav_lsb ? (u >> 8) : (u & 0xFF));
                } else {
                    d += static_cast<char>(u);
                }
            }
            r = scpi::encode_block(d);
            return true;
        }
        return false;
    }

    bool redpitaya_acq(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
        constexpr std::size_t kBuf = 16384;
        int ch = -1;
        auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
        acquire_if_done();
        if (is("ACQ:RST")) {
            const auto k = dig_.kind;
            dig_ = Digitizer{};
            dig_.kind = k;
            dig_.trig = "DISABLED";
            return true;
        }
        if (is("ACQ:DEC:F") || is("ACQ:DEC")) {
            if (q) {
                r = std::to_string(dig_.dec);
                return true;
            }
            const double v = parse_number(a);
            const auto d = static_cast<long>(v);
            const bool factor = h.back().name == "F";
            if (v != std::floor(v) || d < 1 || d > 65536 || (!factor && (d & (d - 1)) != 0)) err(-224, "Illegal parameter value;decimation");
            dig_.dec = static_cast<int>(d);
            return true;
        }
        if (is("ACQ:DATA:UNIT")) {
            const auto u = upper(trim(a));
            if (u != "VOLTS" && u != "RAW") err(-224, "Illegal parameter value");
            dig_.rp_volts = u == "VOLTS";
            return true;
        }
        if (is("ACQ:DATA:FORM")) {
            const auto u = upper(trim(a));
            if (u != "ASCII" && u != "BIN") err(-224, "Illegal parameter value");
            dig_.rp_bin = u == "BIN";
            return true;
        }
        if (is("ACQ:TRIG:DLY")) {
            if (q) r = std::to_string(dig_.dly);
            else {
                const double v = parse_number(a);
                if (v != std::floor(v) || v < -8192 || v > 1e9) err(-222, "Data out of range");
                dig_.dly = static_cast<long>(v);
            }
            return true;
        }
        if (is("ACQ:START")) {
            dig_.rp_started = true;
            dig_.state = Digitizer::State::Stop;
            dig_.have = false;
            return true;
        }
        if (is("ACQ:STOP")) {
            dig_.rp_started = false;
            return true;
        }
        if (is("ACQ:TRIG:STAT") && q) {
            r = dig_.state == Digitizer::State::Wait ? "WAIT" : "TD";
            return true;
        }
        if (is("ACQ:TRIG:FILL") && q) {
            r = dig_.have ? "1" : "0";
            return true;
        }
        if (is("ACQ:TRIG")) {
            const auto u = upper(trim(a));
            if (u != "NOW" && u != "AWG_PE" && u != "EXT_PE" && u != "DISABLED") err(-224, "Illegal parameter value;the emulator triggers on NOW, AWG_PE or EXT_PE");
            if (!dig_.rp_started) err(-221, "Settings conflict;ACQ:START first");
            dig_.trig = u;
            dig_.fs = 125e6 / dig_.dec;
            dig_.points = kBuf;
            dig_.pre = static_cast<std::size_t>(std::clamp<long>(static_cast<long>(kBuf / 2) - dig_.dly, 0, static_cast<long>(kBuf)));
            if (u != "DISABLED") arm(u == "NOW");
            return true;
        }
        if (is("ACQ:SOUR#:DATA") && q) {
            if (ch != 1 && ch != 2) err(-114, "Header suffix out of range");
            if (!dig_.have) err(-230, "Data corrupt or stale;no completed acquisition");
            const double qv = 2.0 / 16384;  // 14-bit ADC over +-1 V
            std::vector<double> v(kBuf);
            for (std::size_t m = 0; m < kBuf; ++m) v[m] = std::clamp(std::round(dig_.data[ch - 1][m] / qv) * qv, -1.0, 1.0 - qv);
            if (dig_.rp_bin) {
                std::string d;
                for (double x : v) {
                    const float f = static_cast<float>(x);
                    std::uint8_t b[4];
                    std::memcpy(b, &f, 4);
                    for (int i = 3; i >= 0; --i) d += static_cast<char>(b[i]);  // big-endian
                }
                r = scpi::encode_block(d);
            } else {
                std::string s = "{";
                char b[32];
                for (std::size_t m = 0; m < kBuf; ++m) {
                    std::snprintf(b, sizeof b, "%s%.7f", m ? "," : "", v[m]);
                    s += b;
                }
                r = s + "}";
            }
            return true;
        }
        return false;
    }

    const InstrumentSimOptions& o_;
    std::mt19937_64 rng_;
    WallClock::time_point epoch_;
    Generator gen_;
    Digitizer dig_;
    std::vector<std::unique_ptr<Port>> ports_;
    std::vector<Client> clients_;
    long long count_ = 0, answered_ = 0;
    bool dropped_ = false, frozen_ = false;
    long long fault_seen_ = 0;
};

}  // namespace

double sim_interpolate(std::span<const double> x, bool cyclic, double u) {
    const double fl = std::floor(u);
    const auto i0 = static_cast<long long>(fl);
    const double f = u - fl;
    const auto n = static_cast<long long>(x.size());
    if (n == 0 || i0 + kHalf < 0 || (!cyclic && i0 - kHalf >= n)) return 0;
    double s = 0;
    for (long long j = i0 - kHalf + 1; j <= i0 + kHalf; ++j) {
        if (j < 0 || (!cyclic && j >= n)) continue;
        s += x[static_cast<std::size_t>(j % n)] * kernel(f - static_cast<double>(j - i0));
    }
    return s;
}

const char* instrument_sim_generators() { return "keysight-33500b|keysight-33600a|rigol-dg800|rigol-dg900|rigol-dg1000z|siglent-sdg|redpitaya"; }
const char* instrument_sim_digitizers() { return "generic-scope|redpitaya"; }

long long run_instrument_sim(const InstrumentSimOptions& o) {
    Sim s(o);
    return s.run();
}

}  // namespace fringe::dev
