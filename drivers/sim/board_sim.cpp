#include "drivers/sim/board_sim.hpp"

#include "estimator/correction.hpp"
#include "estimator/estimator.hpp"
#include "drivers/modbus_board.hpp"
#include "signal_gen/base/constants.hpp"

#include <modbus/modbus.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <chrono>
#include <cmath>
#include <memory>
#include <random>
#include <set>
#include <atomic>
#include <stdexcept>
#include <thread>

namespace fringe::dev {

namespace {

struct Sim {
    const BoardSimOptions& o;
    BoardProfile board;
    modbus_mapping_t* map = nullptr;
    std::mt19937_64 rng;
    std::normal_distribution<double> gauss{0.0, 1.0};
    std::unique_ptr<est::Estimator> dut;
    double analog_s = 0, analog_c = 0;  // the analog signals at the ADC input, V
    bool adc_in_holding = false;        // sin_in/cos_in are holding registers

    explicit Sim(const BoardSimOptions& opt) : o(opt), board(load_board(opt.board)), rng(opt.seed) {
        int hold = 1, in = 1;
        auto extent = [&](const RegisterDef& r) { (r.table == RegTable::Holding ? hold : in) = std::max(r.table == RegTable::Holding ? hold : in, r.address + r.count * r.words()); };
        for (const auto& [role, r] : board.regs) extent(r);
        for (const auto& c : board.checks) extent(c.reg);
        for (const auto& w : board.init) extent(w.reg);
        for (const char* role : {"sin_in", "cos_in"})
            if (const auto* r = board.find(role)) adc_in_holding |= r->table == RegTable::Holding;
        map = modbus_mapping_new(0, 0, hold, in);
        if (!map) throw std::runtime_error(std::string("board-sim: ") + modbus_strerror(errno));
        // The profile's identity checks read what it expects (a LabJack's TEST and PRODUCT_ID).
        for (const auto& c : board.checks) {
            const auto w = encode_register(c.reg, c.expect);
            std::copy(w.begin(), w.end(), slot(c.reg));
        }
        if (board.has_dut_position()) {
            rebuild(nullptr);
            rebased = false;
        }
        put("status", 1);
        put("error_flags", 0);
    }
    ~Sim() { modbus_mapping_free(map); }

    std::uint16_t* slot(const RegisterDef& r) {
        return r.table == RegTable::Holding ? map->tab_registers + r.address : map->tab_input_registers + r.address;
    }
    void put(const std::string& role, double v) {
        if (const auto* r = board.find(role)) {
            const auto w = encode_register(*r, v);
            std::copy(w.begin(), w.end(), slot(*r));
        }
    }
    double get(const std::string& role) {
        const auto* r = board.find(role);
        return r ? decode_register(*r, slot(*r)) : 0.0;
    }
    double convert(double v) {  // one ADC conversion of an analog level, V
        v += o.noise_v * gauss(rng);
        if (o.adc_bits <= 0) return v;
        const double q = 2 * o.adc_range_v / std::ldexp(1.0, o.adc_bits);
        return std::clamp(std::round(v / q), -std::ldexp(1.0, o.adc_bits - 1), std::ldexp(1.0, o.adc_bits - 1) - 1) * q;
    }
    // The on-board estimator, with a correction (what the correction registers hold) or without.
    // The correction reaches it as fringe's own file format (estimator/correction.hpp), so it is
    // applied exactly as `atan2 correction=FILE` applies it, at the registers' quantisation.
    void rebuild(const est::Correction* c) {
        est::EstimatorConfig cfg;
        cfg.sample_rate_hz = 1000.0;  // quasi-static: one conversion per step
        cfg.params = o.params;
        std::string path;
        if (c) {
            char tmpl[] = "/tmp/fringe-board-sim-correction-XXXXXX";
            const int fd = mkstemp(tmpl);
            if (fd < 0) throw std::runtime_error("cannot write the correction file");
            path = tmpl;
            const std::string text = c->to_json().dump();
            const bool ok = ::write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size());
            ::close(fd);
            if (!ok) {
                ::unlink(path.c_str());
                throw std::runtime_error("cannot write the correction file");
            }
            cfg.params["correction"] = path;
        }
        std::unique_ptr<est::Estimator> e;
        try {
            e = est::make(o.estimator, cfg);
        } catch (...) {
            if (!path.empty()) ::unlink(path.c_str());
            throw;
        }
        if (!path.empty()) ::unlink(path.c_str());
        dut = std::move(e);
        rebased = true;  // the position keeps its turns across the rebuild
    }
    // Applies what the correction registers hold (on) or removes the correction. A correction the
    // estimator refuses (amplitudes not positive, an estimator without correction=FILE) is not
    // applied, and correction_enable reads 0 again.
    void apply_correction(bool on) {
        if (!dut) return;
        if (!on) {
            rebuild(nullptr);
            return;
        }
        est::Correction c;
        if (const auto* t = board.find("correction_table_rad"))
            for (int i = 0; i < t->count; ++i) c.table.push_back(decode_register(*t, slot(*t) + i * t->words()));
        if (board.find("correction_offset_rad")) c.offset_rad = get("correction_offset_rad");
        if (board.find("trim_offset_sin_v")) {
            c.has_lissajous = true;
            c.offset_sin_v = get("trim_offset_sin_v");
            c.offset_cos_v = get("trim_offset_cos_v");
            c.amplitude_sin_v = get("trim_amplitude_sin_v");
            c.amplitude_cos_v = get("trim_amplitude_cos_v");
            c.quadrature_error_rad = get("trim_phase_rad");
        }
        try {
            rebuild(&c);
        } catch (const std::exception& e) {
            std::fprintf(stderr, "board-sim: correction not applied: %s\n", e.what());
            rebuild(nullptr);
            put("correction_enable", 0);
        }
    }
    static bool covers(const RegisterDef* r, int a, int n) {
        return r && r->table == RegTable::Holding && r->address < a + n && a < r->address + r->count * r->words();
    }
    // A write of holding registers [a, a + n). With correction_enable declared, the correction is
    // applied (or removed) when that register is written, and writes of the table or trims wait
    // for it; without it, every write of a correction register applies what they hold at once.
    void on_write(int a, int n) {
        bool corr = false;
        for (const char* role : {"correction_table_rad", "correction_offset_rad", "trim_offset_sin_v", "trim_offset_cos_v", "trim_amplitude_sin_v", "trim_amplitude_cos_v",
                                 "trim_phase_rad", "correction_enable"})
            corr |= covers(board.find(role), a, n);
        if (corr) {
            if (const auto* en = board.find("correction_enable")) {
                if (covers(en, a, n)) apply_correction(get("correction_enable") != 0);
            } else {
                apply_correction(true);
            }
            if (!covers(board.find("sin_out"), a, n) && !covers(board.find("cos_out"), a, n)) return;  // no new drive: no new conversion
        }
        // The drive registers hold what the DAC outputs; the analog path adds the board's flaws.
        analog_s = (1 + o.gain_mismatch / 2) * get("sin_out") + o.offset_sin_v;
        analog_c = (1 - o.gain_mismatch / 2) * get("cos_out") + o.offset_cos_v;
        if (dut) {
            const double s = convert(analog_s), c = convert(analog_c);
            double th = 0, om = 0;
            std::uint8_t valid = 0;
            dut->process({std::span(&s, 1), std::span(&c, 1)}, {std::span(&th, 1), std::span(&om, 1), std::span(&valid, 1)});
            if (rebased) {  // a rebuilt estimator starts within a turn: keep the position's turns
                turns_rad = kTwoPi * std::round((last_theta - th) / kTwoPi);
                rebased = false;
            }
            th += turns_rad;
            last_theta = th;
            const double periods = th / kTwoPi;
            const double whole = std::floor(periods);
            put("position_count", whole);
            put("position_fraction", periods - whole);
            put("position_rad", th);
            // bit 0: signal amplitude below 5 % of the ADC range; bit 1: estimator not locked.
            const int flags = (std::hypot(s, c) < 0.05 * o.adc_range_v ? 1 : 0) | (valid ? 0 : 2);
            put("error_flags", flags);
        }
    }
    long long conversions = 0;
    bool rebased = false;
    double turns_rad = 0, last_theta = 0;
    // A read request (function, address, count) that covers an ADC register (sin_in, cos_in).
    bool reads_adc(const std::uint8_t* pdu) const {
        const RegTable t = pdu[0] == MODBUS_FC_READ_INPUT_REGISTERS ? RegTable::Input : RegTable::Holding;
        const int a = pdu[1] << 8 | pdu[2], n = pdu[3] << 8 | pdu[4];
        for (const char* role : {"sin_in", "cos_in"})
            if (const auto* r = board.find(role); r && r->table == t && r->address < a + n && a < r->address + r->words()) return true;
        return false;
    }
    void on_read_inputs() {  // a fresh conversion for every read (unless a fault froze the ADC)
        ++conversions;
        if (o.stale_adc_after >= 0 && conversions > o.stale_adc_after) return;
        put("sin_in", o.nan_adc_after >= 0 && conversions > o.nan_adc_after ? std::nan("") : convert(analog_s));
        put("cos_in", convert(analog_c));
    }
};

// The reply libmodbus would send, captured through a socket pair, then sent to the client one
// byte every trickle_ms.
template <class Reply>
void trickled(modbus_t* ctx, int trickle_ms, const std::atomic<bool>* stop, Reply&& reply) {
    const int real = modbus_get_socket(ctx);
    int sv[2];
    if (socketpair(AF_UNIX, SOCK_STREAM, 0, sv) != 0) { reply(); return; }
    modbus_set_socket(ctx, sv[0]);
    reply();
    modbus_set_socket(ctx, real);
    ::shutdown(sv[0], SHUT_WR);
    std::uint8_t buf[512];
    const ssize_t n = ::recv(sv[1], buf, sizeof buf, 0);
    ::close(sv[0]);
    ::close(sv[1]);
    for (ssize_t i = 0; i < n; ++i) {
        if (stop && stop->load()) return;
        if (::send(real, buf + i, 1, MSG_NOSIGNAL) != 1) return;
        if (i + 1 < n) std::this_thread::sleep_for(std::chrono::milliseconds(trickle_ms));
    }
}

enum class Served { Ok, Drop, Restart };

// One request: faults, then the reply (and the board's reaction to writes).
Served serve_one(Sim& sim, modbus_t* ctx, const std::uint8_t* query, int len, long long& count) {
    const BoardSimOptions& o = sim.o;
    ++count;
    if (o.drop_after >= 0 && count > o.drop_after) return Served::Drop;
    if (o.restart_after >= 0 && count == o.restart_after + 1) return Served::Restart;
    if (o.freeze_after >= 0 && count > o.freeze_after) return Served::Ok;  // read, never answered
    if (o.delay_ms > 0 && count >= o.delay_from && (o.delay_count < 0 || count < o.delay_from + o.delay_count))
        std::this_thread::sleep_for(std::chrono::milliseconds(o.delay_ms));
    auto reply = [&](auto&& f) {
        if (o.trickle_ms > 0) trickled(ctx, o.trickle_ms, o.stop, f);
        else f();
    };
    if (o.exception_every > 0 && count % o.exception_every == 0) {
        reply([&] { modbus_reply_exception(ctx, query, MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE); });
        return Served::Ok;
    }
    const int hl = modbus_get_header_length(ctx);
    const int fc = query[hl];
    // A fresh conversion for every read of the table the ADC registers are in (input
    // registers, or holding registers on boards with one address space, like a LabJack).
    if ((fc == MODBUS_FC_READ_INPUT_REGISTERS || (fc == MODBUS_FC_READ_HOLDING_REGISTERS && sim.adc_in_holding)) && sim.reads_adc(query + hl)) sim.on_read_inputs();
    reply([&] { modbus_reply(ctx, query, len, sim.map); });
    const std::uint8_t* pdu = query + hl;
    if (fc == MODBUS_FC_WRITE_SINGLE_REGISTER) sim.on_write(pdu[1] << 8 | pdu[2], 1);
    else if (fc == MODBUS_FC_WRITE_MULTIPLE_REGISTERS) sim.on_write(pdu[1] << 8 | pdu[2], pdu[3] << 8 | pdu[4]);
    else if (fc == MODBUS_FC_WRITE_AND_READ_REGISTERS) sim.on_write(pdu[5] << 8 | pdu[6], pdu[7] << 8 | pdu[8]);
    return Served::Ok;
}

}  // namespace

long long run_board_sim(const BoardSimOptions& o) {
    auto simp = std::make_unique<Sim>(o);
    long long count = 0;
    std::uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH > MODBUS_RTU_MAX_ADU_LENGTH ? MODBUS_TCP_MAX_ADU_LENGTH : MODBUS_RTU_MAX_ADU_LENGTH];
    auto stopped = [&] { return o.stop && o.stop->load(); };

    if (o.listen.rfind("rtu:", 0) == 0) {
        const std::string dev = o.listen.substr(4);
        modbus_t* ctx = modbus_new_rtu(dev.c_str(), o.baud, 'N', 8, 1);
        if (!ctx) throw std::runtime_error("board-sim: " + dev + ": " + modbus_strerror(errno));
        modbus_set_slave(ctx, o.unit);
        if (modbus_connect(ctx) == -1) {
            const std::string msg = modbus_strerror(errno);
            modbus_free(ctx);
            throw std::runtime_error("board-sim: " + dev + ": " + msg);
        }
        if (o.on_listening) o.on_listening(dev);
        const int fd = modbus_get_socket(ctx);
        while (!stopped()) {
            fd_set rd;
            FD_ZERO(&rd);
            FD_SET(fd, &rd);
            timeval tv{0, 100000};
            if (select(fd + 1, &rd, nullptr, nullptr, &tv) <= 0) continue;
            const int rc = modbus_receive(ctx, query);
            if (rc > 0 && serve_one(*simp, ctx, query, rc, count) != Served::Ok) break;
            // rc == 0: a request for another unit; rc == -1: a garbled frame (CRC): keep serving
        }
        modbus_close(ctx);
        modbus_free(ctx);
        return count;
    }

    if (o.listen.rfind("tcp://", 0) != 0) throw std::runtime_error("board-sim: --modbus expects tcp://HOST:PORT or rtu:/dev/ttyX, got '" + o.listen + "'");
    const std::string hp = o.listen.substr(6);
    const auto colon = hp.rfind(':');
    const std::string host = colon == std::string::npos ? hp : hp.substr(0, colon);
    const int port = colon == std::string::npos ? 502 : std::stoi(hp.substr(colon + 1));
    modbus_t* ctx = nullptr;
    int server = -1;
    auto listen_on = [&](int p) {
        ctx = modbus_new_tcp(host.c_str(), p);
        if (!ctx) throw std::runtime_error(std::string("board-sim: ") + modbus_strerror(errno));
        server = modbus_tcp_listen(ctx, 16);
        if (server == -1) {
            const std::string msg = modbus_strerror(errno);
            modbus_free(ctx);
            throw std::runtime_error("board-sim: listen on " + host + ":" + std::to_string(p) + ": " + msg);
        }
    };
    listen_on(port);
    sockaddr_in addr{};
    socklen_t alen = sizeof addr;
    getsockname(server, reinterpret_cast<sockaddr*>(&addr), &alen);
    const int bound_port = ntohs(addr.sin_port);
    if (o.on_listening) o.on_listening("tcp://" + host + ":" + std::to_string(bound_port));
    std::set<int> clients;
    bool dropped = false;
    while (!stopped() && !dropped) {
        fd_set rd;
        FD_ZERO(&rd);
        FD_SET(server, &rd);
        int maxfd = server;
        for (int c : clients) {
            FD_SET(c, &rd);
            maxfd = std::max(maxfd, c);
        }
        timeval tv{0, 100000};
        if (select(maxfd + 1, &rd, nullptr, nullptr, &tv) <= 0) continue;
        if (FD_ISSET(server, &rd)) {
            const int c = accept(server, nullptr, nullptr);
            if (c >= 0) clients.insert(c);
        }
        bool restart = false;
        for (auto it = clients.begin(); it != clients.end();) {
            const int c = *it;
            if (!FD_ISSET(c, &rd)) { ++it; continue; }
            modbus_set_socket(ctx, c);
            const int rc = modbus_receive(ctx, query);
            if (rc > 0) {
                const Served s = serve_one(*simp, ctx, query, rc, count);
                if (s == Served::Drop) { dropped = true; break; }
                if (s == Served::Restart) { restart = true; break; }
                ++it;
            } else if (rc == -1) {  // closed or broken
                close(c);
                it = clients.erase(it);
            } else {
                ++it;
            }
        }
        if (restart) {  // the board reboots: connections reset, away for a while, fresh registers
            for (int c : clients) close(c);
            clients.clear();
            close(server);
            modbus_free(ctx);
            const auto back = std::chrono::steady_clock::now() + std::chrono::milliseconds(o.restart_down_ms);
            while (!stopped() && std::chrono::steady_clock::now() < back) std::this_thread::sleep_for(std::chrono::milliseconds(10));
            simp = std::make_unique<Sim>(o);
            listen_on(bound_port);
        }
    }
    for (int c : clients) close(c);
    close(server);
    modbus_free(ctx);
    return count;
}

}  // namespace fringe::dev
