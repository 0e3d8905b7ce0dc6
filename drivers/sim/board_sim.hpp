// An emulated Modbus board on libmodbus's server side (`fringe board-sim`), for tests and
// for trying fringe without hardware. Written DAC values (sin_out, cos_out) pass through a
// simulated analog path (gain mismatch, offsets, noise, ADC bits) into the input registers
// (sin_in, cos_in: a fresh conversion per read) and, for a DUT board, into an on-board
// estimator (any registered one) whose position appears in the position registers. A DUT
// profile's correction registers (trims, angle table, offset) are applied to that estimator as
// fringe's correction file when correction_enable is written non-zero (at every write of them
// on a profile without one).
// Fault injection: exception replies, reply delays (all or some requests), replies trickled a
// byte at a time, a board that stops answering (frozen), is killed or restarts on its port, ADC
// registers that stop updating (repeating old data) or turn to NaN.
#pragma once

#include <nlohmann/json.hpp>

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>

namespace fringe::dev {

struct BoardSimOptions {
    std::string listen;  // "tcp://127.0.0.1:PORT" (port 0: a free one) or "rtu:/dev/ttyX"
    std::string board = "generic-aio";
    int unit = 1;
    int baud = 115200;
    // On-board estimator (DUT boards) and its flaws.
    std::string estimator = "atan2";
    nlohmann::json params = nlohmann::json::object();
    double offset_sin_v = 0, offset_cos_v = 0;
    double gain_mismatch = 0;  // sin gain 1 + g/2, cos gain 1 - g/2
    double noise_v = 0;        // rms, per conversion
    int adc_bits = 16;
    double adc_range_v = 1.25;
    std::uint64_t seed = 1;
    // Faults.
    int exception_every = 0;       // every Nth request answers SLAVE_OR_SERVER_FAILURE (0: never)
    int delay_ms = 0;              // before every reply (or those delay_from.. below)
    long long delay_from = 1;      // the first request (counted from 1) delay_ms applies to
    long long delay_count = -1;    // how many requests from delay_from are delayed (-1: all)
    int trickle_ms = 0;            // send each reply one byte at a time, this far apart (0: at once)
    long long drop_after = -1;     // after this many requests, close every connection and stop (-1: never)
    long long freeze_after = -1;   // after this many requests, read requests but never answer (-1: never)
    long long restart_after = -1;  // after this many requests, close everything, stay away restart_down_ms,
    int restart_down_ms = 300;     // then listen again on the same port with fresh registers (once; TCP)
    long long stale_adc_after = -1;  // after this many ADC conversions the input registers stop updating
    long long nan_adc_after = -1;    // after this many ADC conversions sin_in reads NaN (float registers)
    std::function<void(const std::string& where)> on_listening;  // "tcp://127.0.0.1:40123" or the tty
    const std::atomic<bool>* stop = nullptr;
};

// Serves until *stop, a drop fault, or an error. Returns the number of requests answered.
// Throws std::runtime_error (with libmodbus's message) if it cannot listen.
long long run_board_sim(const BoardSimOptions& o);

}  // namespace fringe::dev
