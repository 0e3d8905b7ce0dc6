// Emulated SCPI bench instruments over real TCP sockets (`fringe instrument-sim`, docs/bench.md):
// one arbitrary waveform generator (a dialect of scpi_instruments.cpp: keysight-33500b,
// keysight-33600a, rigol-dg800/dg900/dg1000z, siglent-sdg, redpitaya) and one digitizer
// (generic-scope `:WAV` readout, or redpitaya acquisition), wired by a simulated analog link:
// what the generator plays reaches the digitizer delayed (delay_s), on a generator clock
// clock_ppm fast relative to the digitizer's, scaled (gain), shifted (offset_v), with noise
// and a one-pole bandwidth; the digitizer samples it at its own clock with a Kaiser-windowed
// sinc interpolator. The generator's sync output is wired to the digitizer's EXT trigger.
// IEEE 488.2 behaviour: error queue (-113 "Undefined header", 0 "No error"), *IDN?, *OPC?,
// *RST, *CLS, definite and indefinite blocks. Faults: go silent, drop the connections, die,
// freeze or cut a reply short at a named command (mid-acquisition), delay every reply, and
// hostile text (an *IDN? of any length or content, error-queue text with escape sequences).
// The parsing, transport and link are one core (instrument_sim_core.hpp, instrument_sim.cpp);
// each dialect is a file of its own: instrument_sim_keysight.cpp, _rigol, _siglent,
// _redpitaya (generator and acquisition), _scope.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <span>
#include <string>

namespace fringe::dev {

struct InstrumentSimOptions {
    std::string generator = "keysight-33500b";
    std::string digitizer = "generic-scope";
    std::string host = "127.0.0.1";
    int generator_port = 5025, digitizer_port = 5026;  // 0: a free port; a Red Pitaya pair shares the generator's port
    // The analog link and the clocks.
    double delay_s = 0;        // generator output to digitizer input
    double clock_ppm = 0;      // the generator's clock runs this much fast relative to the digitizer's
    double gain = 1, offset_v = 0;
    double noise_v = 0;        // rms per sample at the digitizer input
    double bandwidth_hz = 0;   // one-pole low-pass at the digitizer input (0: none)
    double digitizer_range_v = 2.0;  // generic-scope full scale +-range
    std::size_t memory_samples = 0;  // generator memory per channel (0: the model's)
    std::uint64_t seed = 1;
    // Faults, counted in commands over all connections.
    long long silent_after = -1;  // then read and never answer
    long long drop_after = -1;    // then close every connection and return
    double exit_after_s = 0;      // 0: until *stop
    // At the fault_count-th command that starts with fault_on (any case, e.g. ":WAV:DATA?"):
    // "drop" closes every connection and returns (the instrument died), "freeze" reads and
    // never answers again, "truncate" sends the first half of that reply and then freezes.
    std::string fault, fault_on;
    long long fault_count = 1;
    double reply_delay_s = 0;     // every reply this late
    // Hostile text: *IDN? answers (empty: the model's), the generator's padded to idn_bytes;
    // after each command that starts with error_on, the error queue gets -200,"error_text".
    std::string generator_idn, digitizer_idn, error_on, error_text;
    std::size_t idn_bytes = 0;
    // role ("generator", "digitizer") and the URI a fringe scenario names it by.
    std::function<void(const std::string& role, const std::string& uri)> on_listening;
    const std::atomic<bool>* stop = nullptr;
};

// Serves until *stop, exit_after_s, or a drop fault; returns the commands answered. Throws
// std::runtime_error naming the problem (unknown dialect, port in use).
long long run_instrument_sim(const InstrumentSimOptions& o);

// The generator dialects and digitizers the emulator knows.
const char* instrument_sim_generators();  // "keysight-33500b|..."
const char* instrument_sim_digitizers();

// Band-limited value of a played channel at (fractional) sample position u: x[j] outside
// 0..n-1 is 0 V, or wraps when cyclic (j >= 0 only: nothing before the start). Exposed for tests.
double sim_interpolate(std::span<const double> x, bool cyclic, double u);

}  // namespace fringe::dev
