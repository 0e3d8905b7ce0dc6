// The SCPI instrument emulator's shared core (instrument_sim_core.hpp): message parsing, the
// TCP transport, the error queue, the dispatch to the dialects, the analog link, and the
// public entry points of instrument_sim.hpp.
#include "drivers/sim/instrument_sim_core.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <stdexcept>
#include <thread>

namespace fringe::dev {

namespace {

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

}  // namespace

namespace isim {

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

Sim::Sim(const InstrumentSimOptions& o) : o_(o), rng_(o.seed) {
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

long long Sim::run() {
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

std::string Sim::idn_for(const std::string& model) {
    if (model == "keysight-33500b") return "Keysight Technologies,33522B,MY00000001,4.00-3.15-2.00-58-00";
    if (model == "keysight-33600a") return "Keysight Technologies,33622A,MY00000002,A.02.03-3.15-03.64-00.01";
    if (model == "rigol-dg800") return "Rigol Technologies,DG822,DG8A000000001,00.02.05";
    if (model == "rigol-dg900") return "Rigol Technologies,DG952,DG9A000000001,00.02.05";
    if (model == "rigol-dg1000z") return "Rigol Technologies,DG1062Z,DG1ZA000000001,03.01.12";
    if (model == "siglent-sdg") return "Siglent Technologies,SDG2042X,SDG2XSIM000001,2.01.01.35R3";
    if (model == "redpitaya") return "REDPITAYA,INSTR2020,0,01-02";
    return "FRINGE,SIM-DIGITIZER,0,1.0";
}

std::string Sim::uri(const Port& p, const std::string& model) const {
    return "scpi+tcp://" + o_.host + ":" + std::to_string(p.port) + "?model=" + model;
}

void Sim::listen(Port& p) {
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

bool Sim::serve(Client& c) {
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

int Sim::scan(const std::string& b, std::size_t& end, std::vector<std::size_t>& semis, std::vector<std::size_t>& block_ends, std::string& bad) {
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

void Sim::push_error(Port& p, const SimError& e) {
    if (p.errors.size() >= 20) {
        p.errors.back() = {-350, "Queue overflow"};
        return;
    }
    p.errors.push_back(e);
}

std::optional<std::string> Sim::execute(Port& p, const std::string& unit) {
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

GenChannel& Sim::chan(int suffix) {
    if (suffix == -1) suffix = 1;
    if (suffix < 1 || suffix > 2) err(-114, "Header suffix out of range");
    return gen_.ch[static_cast<std::size_t>(suffix - 1)];
}

void Sim::check_levels(const GenChannel& c) {
    if (std::fabs(c.offset_v) + c.vpp / 2 > gen_.max_out_v + 1e-9) err(-221, "Settings conflict;amplitude and offset exceed the output range");
}

std::vector<double> Sim::codes_to_norm(const std::string& data, int bytes, bool little, bool is_signed, double full) {
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

std::string Sim::block_arg(const std::string& a) {
    try {
        return scpi::decode_block(ltrim(a), kMaxMessage);
    } catch (const std::exception&) {
        err(-160, "Block data error");
    }
}

void Sim::trigger(std::array<bool, 2> which, bool skew) {
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

void Sim::sync_out(double t) {
    const bool waiting = dig_.state == Digitizer::State::Wait;
    const bool on_gen = dig_.kind == "generic-scope" ? dig_.trig == "EXT" : (dig_.trig == "AWG_PE" || dig_.trig == "EXT_PE");
    if (waiting && on_gen) {
        dig_.trig_s = t;
        dig_.state = Digitizer::State::Run;
    }
}

double Sim::rate(const GenChannel& c) const {
    if (gen_.model == "redpitaya") return c.rp_freq_hz * static_cast<double>(c.norm.size());
    return c.rate_hz;
}

void Sim::output_changed(GenChannel& c) {
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

void Sim::acquire_if_done() {
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

void Sim::arm(bool immediate) {
    dig_.have = false;
    dig_.trig_s.reset();
    dig_.state = Digitizer::State::Wait;
    if (immediate) {
        dig_.trig_s = now_s() + static_cast<double>(dig_.pre) / dig_.fs;
        dig_.state = Digitizer::State::Run;
    }
}

}  // namespace isim

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
    isim::Sim s(o);
    return s.run();
}

}  // namespace fringe::dev
