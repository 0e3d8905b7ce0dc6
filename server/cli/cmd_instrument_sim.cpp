// fringe instrument-sim: emulated SCPI instruments (a waveform generator and a digitizer
// wired by a simulated analog link) on real TCP sockets, for tests, demos and pyvisa scripts.
#include "server/cli/commands.hpp"
#include "drivers/sim/instrument_sim.hpp"

#include <atomic>
#include <cctype>
#include <csignal>
#include <cstdio>

namespace fringe::cli {

namespace {

struct InstrumentSimCli {
    dev::InstrumentSimOptions o;
    bool bench = false;
    int port = -1;
    CLI::App* app = nullptr;
};

// Hostile text given on the command line: \xNN is that byte (NUL included), \\ a backslash.
std::string decode_escapes(const std::string& s) {
    std::string o;
    for (std::size_t i = 0; i < s.size(); ++i) {
        if (s[i] == '\\' && i + 1 < s.size() && s[i + 1] == '\\') {
            o += '\\';
            ++i;
        } else if (s[i] == '\\' && i + 3 < s.size() && s[i + 1] == 'x' && std::isxdigit(static_cast<unsigned char>(s[i + 2])) &&
                   std::isxdigit(static_cast<unsigned char>(s[i + 3]))) {
            o += static_cast<char>(std::stoi(s.substr(i + 2, 2), nullptr, 16));
            i += 3;
        } else {
            o += s[i];
        }
    }
    return o;
}

std::atomic<bool> g_isim_stop{false};
void on_isim_signal(int) { g_isim_stop = true; }

int run_instrument_sim_cli(InstrumentSimCli& c) {
    // --bench: the pair fixtures/scenarios/scpi-awg-digitizer.json names (Keysight 33500B on
    // 5025, generic scope on 5026); --port 0 moves both to free ports.
    if (c.port >= 0) c.o.generator_port = c.o.digitizer_port = c.port;
    // The bench's link, unless given: what the fixture's alignment limits expect.
    auto unset = [&](const char* opt) { return c.app->count(opt) == 0; };
    if (c.bench) {
        if (unset("--delay-s")) c.o.delay_s = 15e-6;
        if (unset("--clock-ppm")) c.o.clock_ppm = 20;
        if (unset("--gain")) c.o.gain = 0.95;
        if (unset("--offset-v")) c.o.offset_v = 0.002;
        if (unset("--noise-v")) c.o.noise_v = 1e-4;
    }
    c.o.generator_idn = decode_escapes(c.o.generator_idn);
    c.o.digitizer_idn = decode_escapes(c.o.digitizer_idn);
    c.o.error_text = decode_escapes(c.o.error_text);
    c.o.stop = &g_isim_stop;
    std::signal(SIGINT, on_isim_signal);
    std::signal(SIGTERM, on_isim_signal);
    c.o.on_listening = [](const std::string& role, const std::string& uri) {
        std::printf("instrument-sim %s %s\n", role.c_str(), uri.c_str());
        std::fflush(stdout);
    };
    const long long n = dev::run_instrument_sim(c.o);
    std::printf("instrument-sim: %lld commands answered\n", n);
    return kExitOk;
}

}  // namespace

Command add_instrument_sim(CLI::App& app) {
    auto c = std::make_shared<InstrumentSimCli>();
    auto* s = app.add_subcommand("instrument-sim", "Emulated SCPI instruments (a waveform generator and a digitizer on one simulated analog link) over TCP");
    c->app = s;
    s->add_flag("--bench", c->bench,
                "The bench of fixtures/scenarios/scpi-awg-digitizer.json: keysight-33500b on 5025, generic-scope on 5026, link 15 us, 20 ppm, gain 0.95, 2 mV, 0.1 mV noise (options given override)");
    s->add_option("--generator", c->o.generator, std::string("Generator dialect: ") + dev::instrument_sim_generators())->capture_default_str();
    s->add_option("--digitizer", c->o.digitizer, std::string("Digitizer: ") + dev::instrument_sim_digitizers())->capture_default_str();
    s->add_option("--host", c->o.host, "IPv4 address to listen on")->capture_default_str();
    s->add_option("--generator-port", c->o.generator_port, "Generator's TCP port (0: a free one, printed)")->capture_default_str();
    s->add_option("--digitizer-port", c->o.digitizer_port, "Digitizer's TCP port (0: a free one, printed; a Red Pitaya pair shares the generator's)")->capture_default_str();
    s->add_option("--port", c->port, "Both ports (0: free ones, printed)");
    s->add_option("--delay-s", c->o.delay_s, "Link: generator output to digitizer input, s")->capture_default_str();
    s->add_option("--clock-ppm", c->o.clock_ppm, "Link: the generator's clock runs this much fast relative to the digitizer's, ppm")->capture_default_str();
    s->add_option("--gain", c->o.gain, "Link gain")->capture_default_str();
    s->add_option("--offset-v", c->o.offset_v, "Link offset, V")->capture_default_str();
    s->add_option("--noise-v", c->o.noise_v, "Noise at the digitizer input, V rms")->capture_default_str();
    s->add_option("--bandwidth-hz", c->o.bandwidth_hz, "One-pole bandwidth at the digitizer input, Hz (0: none)")->capture_default_str();
    s->add_option("--digitizer-range-v", c->o.digitizer_range_v, "generic-scope full scale +-V")->capture_default_str();
    s->add_option("--memory-samples", c->o.memory_samples, "Generator memory per channel (0: the model's)")->capture_default_str();
    s->add_option("--seed", c->o.seed, "Noise seed")->capture_default_str();
    s->add_option("--silent-after", c->o.silent_after, "Fault: after N commands read and never answer");
    s->add_option("--drop-after", c->o.drop_after, "Fault: after N commands close every connection and exit");
    s->add_option("--exit-after", c->o.exit_after_s, "Exit after S seconds (0: at SIGTERM/SIGINT)");
    s->add_option("--fault", c->o.fault, "Fault at --fault-on: drop (close every connection and exit: the instrument died), freeze (never answer again), "
                                         "truncate (send half of that reply, then freeze)")
        ->check(CLI::IsMember({"drop", "freeze", "truncate"}));
    s->add_option("--fault-on", c->o.fault_on, "The command the fault happens at, by its start (any case): ':WAV:DATA?' is mid-acquisition");
    s->add_option("--fault-count", c->o.fault_count, "At its Nth occurrence")->capture_default_str()->check(CLI::PositiveNumber);
    s->add_option("--reply-delay-s", c->o.reply_delay_s, "Fault: every reply this many seconds late")->capture_default_str()->check(CLI::NonNegativeNumber);
    s->add_option("--generator-idn", c->o.generator_idn, "The generator's *IDN? answer (\\xNN: any byte)");
    s->add_option("--digitizer-idn", c->o.digitizer_idn, "The digitizer's *IDN? answer (\\xNN: any byte)");
    s->add_option("--idn-bytes", c->o.idn_bytes, "Pad the generator's *IDN? answer to this many bytes");
    s->add_option("--error-on", c->o.error_on, "After each command starting with this, queue the error -200,\"--error-text\"");
    s->add_option("--error-text", c->o.error_text, "Text of that error (\\xNN: any byte)");
    return {s, [c] { return run_instrument_sim_cli(*c); }};
}

}  // namespace fringe::cli
