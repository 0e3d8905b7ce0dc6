// The SCPI instrument emulator's shared core (instrument_sim.cpp): IEEE 488.2 message
// parsing and header matching, the TCP transport, the error queue, the instruments' state,
// the command dispatch and the analog link from generator to digitizer. Each instrument
// dialect answers its own commands in a file of its own (instrument_sim_<dialect>.cpp) as a
// member of Sim; a new dialect is one such file, its declaration below and its line in
// Sim::execute. Internal to drivers/sim: the public interface is instrument_sim.hpp.
#pragma once

#include "drivers/sim/instrument_sim.hpp"

#include "drivers/scpi.hpp"
#include "signal_gen/base/constants.hpp"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <string_view>
#include <vector>

namespace fringe::dev::isim {

constexpr std::size_t kMaxMessage = 600u << 20;  // a message (with its blocks) larger than this closes the connection

// ---- SCPI header matching ----
struct Node {
    std::string name;
    int suffix = -1;  // -1: none given
};
// SCPI short form: the first four letters, three when the fourth is a vowel (IEEE 488.2 / SCPI 6.2.1).
std::string short_form(std::string s);
std::vector<Node> parse_header(std::string_view h);
// Pattern "[SOUR#]:FUNC:ARB:SRAT": [..] optional, '#' a numeric suffix captured in *ch (-1 if
// absent). Nodes without '#' must carry the pattern's own suffix (DAC16) or none.
struct PatNode {
    std::string name;
    bool optional = false, capture = false;
    int suffix = -1;
};
std::vector<PatNode> parse_pattern(std::string_view p);
bool match_from(const std::vector<Node>& h, std::size_t i, const std::vector<PatNode>& p, std::size_t j, int* ch);

bool starts_with_ci(std::string_view s, std::string_view prefix);

std::string upper(std::string s);
std::string trim(std::string_view s);
// Leading whitespace only: a block's last data bytes may look like whitespace.
std::string ltrim(std::string_view s);
std::vector<std::string> split_commas(std::string_view s);
std::string fmt(double v);

struct SimError {
    int code;
    std::string text;
};
[[noreturn]] void err(int code, const std::string& text);

double parse_number(const std::string& a);
bool parse_bool(const std::string& a);


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
    explicit Sim(const InstrumentSimOptions& o);
    ~Sim() {
        for (auto& c : clients_) ::close(c.fd);
        for (auto& p : ports_)
            if (p->listen_fd >= 0) ::close(p->listen_fd);
    }

    long long run();

private:
    static std::string idn_for(const std::string& model);
    std::string uri(const Port& p, const std::string& model) const;
    void listen(Port& p);
    double now_s() const { return std::chrono::duration<double>(WallClock::now() - epoch_).count(); }

    // Splits complete messages off c.in (a newline outside blocks ends one) and answers them.
    bool serve(Client& c);
    // 1: a message ends at `end` (';' positions in semis); 0: need more; -1: a bad block header.
    static int scan(const std::string& b, std::size_t& end, std::vector<std::size_t>& semis, std::vector<std::size_t>& block_ends, std::string& bad);
    void push_error(Port& p, const SimError& e);

    // ---- command dispatch ----
    std::optional<std::string> execute(Port& p, const std::string& unit);

    GenChannel& chan(int suffix);
    void check_levels(const GenChannel& c);
    std::vector<double> codes_to_norm(const std::string& data, int bytes, bool little, bool is_signed, double full);
    static std::string block_arg(const std::string& a);

    // The trigger that starts the armed channels (output on, data loaded) now; without channel
    // sync the second channel starts 1.5 of its samples late.
    void trigger(std::array<bool, 2> which, bool skew);
    // The generator's sync output, wired to the digitizer's trigger input.
    void sync_out(double t);
    double rate(const GenChannel& c) const;
    // Output on in continuous (untriggered) mode starts playing at once.
    void output_changed(GenChannel& c);

    // ---- the analog link: the record, sampled on the digitizer's clock ----
    void acquire_if_done();
    void arm(bool immediate);

    // ---- the dialects, one file each ----
    // Each answers a parsed command (h: header nodes, q: a query, a: its arguments) into r
    // and returns true, or returns false for a header it does not know (execute() then
    // queues -113 "Undefined header"); a bad argument throws SimError via err().
    bool keysight(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r);       // instrument_sim_keysight.cpp
    bool rigol(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r);          // instrument_sim_rigol.cpp
    bool siglent(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r);        // instrument_sim_siglent.cpp
    bool redpitaya_gen(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r);  // instrument_sim_redpitaya.cpp
    bool redpitaya_acq(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r);  // instrument_sim_redpitaya.cpp
    bool scope(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r);          // instrument_sim_scope.cpp

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

}  // namespace fringe::dev::isim
