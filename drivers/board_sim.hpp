// An emulated Modbus board on libmodbus's server side (`fringe board-sim`), for tests and
// for trying fringe without hardware. Written DAC values (sin_out, cos_out) pass through a
// simulated analog path (gain mismatch, offsets, noise, ADC bits) into the input registers
// (sin_in, cos_in: a fresh conversion per read) and, for a DUT board, into an on-board
// estimator (any registered one) whose position appears in the position registers.
// Fault injection: exception replies, reply delays, dropping the connection.
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
    int delay_ms = 0;              // before every reply
    long long drop_after = -1;     // after this many requests, close every connection and stop (-1: never)
    std::function<void(const std::string& where)> on_listening;  // "tcp://127.0.0.1:40123" or the tty
    const std::atomic<bool>* stop = nullptr;
};

// Serves until *stop, a drop fault, or an error. Returns the number of requests answered.
// Throws std::runtime_error (with libmodbus's message) if it cannot listen.
long long run_board_sim(const BoardSimOptions& o);

}  // namespace fringe::dev
