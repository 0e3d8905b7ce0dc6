// Live acquisition through sigrok (issue 29): any device libsigrok drives, recorded by Debian's
// `sigrok-cli` run as a child process (no shell, its own process group) whose stdout streams
// into the caller: logic channels as `-O binary` (raw units, one bit per enabled channel in the
// device's channel order, remapped here to the order the caller named them), analog channels as
// `-O analog` (one "NAME: value unit" line per sample and channel). docs/sigrok-live.md.
//
// Drop accounting: sigrok-cli reports no lost samples. What can be measured is stated in
// stats(): samples received against wall-clock time x sample rate since start (meaningful for a
// device that samples in real time; the demo driver generates on demand, see the doc) and an
// exact count against limit_samples when one is set. Nothing more is claimed.
#pragma once

#include "device.hpp"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdint>
#include <deque>
#include <string>
#include <sys/types.h>
#include <utility>
#include <vector>

namespace fringe::dev {

struct SigrokLiveConfig {
    std::string driver;                       // "demo", "fx2lafw", "fx2lafw:conn=1.5" (sigrok-cli -d)
    // Instead of a driver: a recorded session file replayed through the same path (sigrok-cli
    // -i FILE -O binary): logic only; its samplerate, channels and sample count come from
    // `sigrok-cli -i FILE --show` (samplerate_hz 0: the file's; otherwise it must match), and the
    // replay ends after exactly its sample count. For tests and for re-scoring a recorded DUT.
    std::string input_file;
    double samplerate_hz = 0;                 // --config samplerate=
    std::vector<std::string> logic_channels;  // bit k of a logic sample = logic_channels[k] (at most 64)
    std::vector<std::string> analog_channels; // analog[c] = analog_channels[c]
    std::uint64_t limit_samples = 0;          // 0: continuous
    std::vector<std::pair<std::string, std::string>> config;  // extra --config key=value
    std::string program = "sigrok-cli";       // a path, or a name looked up on PATH
    // A channel group the extra config applies to (sigrok-cli -g, e.g. "Logic" for the demo's
    // pattern=incremental). sigrok-cli 0.7 applies every --config to that group, where
    // samplerate is "not applicable": with a group, samplerate is not sent and samplerate_hz
    // must be the device's current rate (the demo's default: 200 kHz).
    std::string channel_group;
    int scan_timeout_ms = 10000;              // the `--scan` that validates channel names
};

class SigrokLive {
public:
    explicit SigrokLive(SigrokLiveConfig cfg);
    ~SigrokLive();
    SigrokLive(const SigrokLive&) = delete;
    SigrokLive& operator=(const SigrokLive&) = delete;

    // Scans the device (driver and channel names checked against sigrok-cli's answer), then
    // spawns the acquisition. Throws DeviceError("sigrok:<driver>", cause).
    void start();
    // The scan and channel check start() begins with, on its own (a device opened checks its
    // driver and channels before any acquisition); start() does not repeat it.
    void probe();
    // Up to max samples: logic[i] bit k = logic_channels[k]; analog[c][i] for analog_channels[c]
    // (the unit's base SI unit: V, A, ...). Ok with 0 frames: the end (limit reached, child
    // exited); Timeout: nothing within timeout_ms; Error: the child died or its output cannot
    // be parsed (message: the cause, exit status and sigrok-cli's stderr tail).
    StreamResult read(std::size_t max, std::vector<std::uint64_t>& logic, std::vector<std::vector<double>>& analog, int timeout_ms);
    // SIGTERM (and SIGCONT, for a stopped child) to the group, SIGKILL after 1 s, reaped.
    // Idempotent; the destructor calls it.
    void stop();
    nlohmann::json stats() const;

    const std::string& device_name() const { return name_; }
    // The sample rate in use (a replayed file's own, once probed).
    double samplerate_hz() const { return cfg_.samplerate_hz; }
    pid_t pid() const { return pid_; }
    // The command line start() runs (argv), for logs and tests.
    std::vector<std::string> command() const;
    // The device's channels in its own order, as `--scan` named them (after start()).
    const std::vector<std::string>& device_channels() const { return device_channels_; }

private:
    void validate() const;
    void scan();
    void show_file();  // scan() for an input_file
    void drain_stderr();
    bool reap(int wait_ms);  // true when the child has been reaped
    std::string exit_text() const;
    std::string fail(const std::string& cause);  // sets the error, returns the message
    bool parse_stdout(std::string& error);       // consumes buf_ into frames; false: unparsable
    std::size_t frames_ready() const;
    bool analog_mode() const { return !cfg_.analog_channels.empty(); }

    SigrokLiveConfig cfg_;
    std::string name_;
    std::vector<std::string> device_channels_;
    std::vector<int> logic_bit_;  // bit of logic_channels[k] in the binary unit
    std::size_t unitsize_ = 0;
    std::size_t file_unitsize_ = 0;  // input_file: the session's unit, from --show
    pid_t pid_ = -1;
    int in_fd_ = -1, out_fd_ = -1, err_fd_ = -1;
    bool probed_ = false, started_ = false, stopped_ = false, stdout_eof_ = false, reaped_ = false, ended_ = false;
    int wait_status_ = 0;
    std::string error_;
    std::string buf_;          // unparsed stdout bytes
    std::string stderr_tail_;  // last kStderrTail bytes
    std::vector<std::deque<double>> analog_q_;
    std::vector<std::uint64_t> logic_q_;  // decoded samples from logic_head_ on
    std::size_t logic_head_ = 0;
    bool identity_bits_ = false;           // logic_channels are the device's first ones, in order
    std::uint64_t delivered_ = 0, received_ = 0, bytes_ = 0;
    std::string exit_note_;
    std::chrono::steady_clock::time_point t0_, t_first_;  // spawn; first stdout byte
    std::chrono::steady_clock::time_point t_end_;  // the child reaped: the clocks of stats() stop
    bool have_first_ = false;
};

}  // namespace fringe::dev
