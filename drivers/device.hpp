// The Device interface (README "Bench drivers"): one interface for the
// simulated loopback, capture replay, Modbus boards and USB streaming boards, opened by URI
// (`loopback:?adc_bits=12&noise_v=1e-4`, `capture:/path/x.fcap`, `modbus+tcp://...`,
// `usb:1209:ec01`). Settings describe themselves. Configuration and control throw
// DeviceError naming the device and the native cause; the stream path returns a status with
// exact counts and never throws per block. Sample loss is never silent.
#pragma once

#include "signal_gen/base/params.hpp"

#include <nlohmann/json.hpp>

#include <atomic>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace fringe::dev {

class DeviceError : public std::runtime_error {
public:
    DeviceError(const std::string& device, const std::string& message)
        : std::runtime_error(device + ": " + message), device_(device) {}
    const std::string& device() const { return device_; }

private:
    std::string device_;
};

// A run was cancelled while the device waited (a retry, a reconnect, a settle): thrown by a
// device told of the cancel (Device::set_cancel), so a cancel does not wait out a failing board.
class Cancelled : public DeviceError {
public:
    explicit Cancelled(const std::string& device) : DeviceError(device, "cancelled") {}
};

// One owner per device at a time, across processes and the service: an exclusive flock(2) on
// a file named after the resolved device (DeviceLock::key_for) in lock_dir(). Released when
// the device is closed, or by the kernel when its process ends (nothing stale survives a
// crash). A device held elsewhere is a DeviceError "busy: ... is in use by pid N (command)".
class DeviceLock;

enum class StreamStatus {
    Ok,
    Timeout,    // no data within the timeout (stalled device)
    Overflow,   // input samples were lost (dropped = exact count)
    Underflow,  // the output ran dry (dropped = samples not played)
    Error,      // the device failed (gone, unplugged); message says why
};
const char* to_string(StreamStatus s);

struct StreamResult {
    StreamStatus status = StreamStatus::Ok;
    std::size_t frames = 0;        // frames transferred by this call
    std::uint64_t first_index = 0; // stream index of the first frame (input)
    std::uint64_t dropped = 0;     // frames lost before them (overflow/underflow)
    std::string message;
};

// What the device's converter chain adds to the signal, for bounds from the signal as
// delivered (quantisation and analog noise); known = false when the device cannot say.
struct ConverterInfo {
    bool known = false;
    int dac_bits = 0, adc_bits = 0;   // 0: ideal (or absent)
    double dac_range_v = 0, adc_range_v = 0;  // full scale is [-range_v, range_v)
    double dac_step_v = 0, adc_step_v = 0;  // quantisation step when given directly (register scale)
    double noise_at_adc_v = 0;        // analog noise rms per channel at the ADC input
    // Noise the device adds to the signal, rms per channel (V): quantisation as white noise of
    // q^2/12 per converter plus analog noise, as the device judges it (a loopback whose ADC
    // re-reads its own DAC's grid adds no second quantisation).
    double added_noise_v = 0;
    std::string note;                 // what was assumed
    // Quantisation step, V (0: ideal): the explicit step, else 2*range/2^bits.
    double dac_q_v() const { return dac_step_v > 0 ? dac_step_v : dac_bits > 0 ? 2 * dac_range_v / static_cast<double>(1ull << dac_bits) : 0.0; }
    double adc_q_v() const { return adc_step_v > 0 ? adc_step_v : adc_bits > 0 ? 2 * adc_range_v / static_cast<double>(1ull << adc_bits) : 0.0; }
    // DAC and ADC quantisation independent of each other, plus the analog noise.
    double independent_noise_v() const {
        return std::sqrt(dac_q_v() * dac_q_v() / 12 + adc_q_v() * adc_q_v() / 12 + noise_at_adc_v * noise_at_adc_v);
    }
};

struct DeviceInfo {
    std::string driver;       // "loopback", "capture", "modbus", "usb"
    std::string uri;
    std::string description;
    std::string board_id;     // DUT / board identification for the run history
    bool streaming = false;   // output/input streams
    bool step_mode = false;   // static pair, settle, read back
    bool dut_position = false;
    bool needs_output = true; // false: an input-only source (capture replay)
    int latency_samples = 0;  // known input delay relative to the output, samples
    nlohmann::json settings = nlohmann::json::object();  // resolved settings
    ConverterInfo converter;
    // Instrument mode (issue 14): a waveform generator plays whole channels from its memory
    // (play), a digitizer or scope records a block (record). Such devices run on their own
    // clocks with an unknown delay between output and input: the run engine aligns truth from
    // the signals (server/align.*) before scoring. can_play: output instrument; can_record:
    // input instrument; own_clock: output and input are not sample-locked (the engine must
    // estimate delay, clock ratio, gain and offset).
    bool can_play = false, can_record = false, own_clock = false;
    std::size_t max_play_samples = 0;  // generator memory per channel (0: unlimited)
};
void to_json(nlohmann::json& j, const DeviceInfo& d);
void to_json(nlohmann::json& j, const ConverterInfo& c);

struct StepResult {
    double sin_v = 0, cos_v = 0;         // measured (averaged) ADC pair
    std::optional<double> dut_theta_rad; // the DUT's own interpolated position, if it has one
};

class Device {
public:
    virtual ~Device() = default;
    virtual DeviceInfo info() const = 0;

    // The run's cancel flag (may be null): a device that waits (retries, reconnects, settles)
    // checks it and throws Cancelled. Devices that never wait long ignore it.
    virtual void set_cancel(const std::atomic<bool>* cancel) { (void)cancel; }

    // Streaming (DAC out, ADC in) at one sample rate. Throws DeviceError if unsupported.
    virtual void start(double sample_rate_hz) = 0;
    // Queue output frames (V). Non-blocking for simulated devices.
    virtual StreamResult write(std::span<const double> sin_v, std::span<const double> cos_v) = 0;
    // The last write has been made. A device that sends whole frames (USB) sends the
    // remainder now as the stream's final, short frame; others have nothing to do.
    virtual void end_of_output() {}
    // Read up to sin_v.size() input frames (V).
    virtual StreamResult read(std::span<double> sin_v, std::span<double> cos_v, int timeout_ms) = 0;
    virtual void stop() = 0;

    // Sources that carry truth (capture replay) fill theta/omega for the frames of the last
    // read; others return false.
    virtual bool last_truth(std::span<double> theta_rad, std::span<double> omega_rad_s) {
        (void)theta_rad; (void)omega_rad_s;
        return false;
    }
    // A DUT read out alongside the stream (ABZ lines in a capture, DeviceInfo::dut_position)
    // fills its position (rad, NaN where it has none) for the frames of the last read; what
    // the readout counted (edges, illegal transitions, index checks) is dut_readout().
    virtual bool last_dut(std::span<double> theta_rad) {
        (void)theta_rad;
        return false;
    }
    virtual nlohmann::json dut_readout() const { return nullptr; }

    // Instrument mode (DeviceInfo::can_play / can_record). play: upload both channels (V) at
    // sample_rate_hz and start the output; cyclic repeats the block until stop_output, else it
    // plays once. record: acquire up to sin_v.size() input frames at (nominally)
    // sample_rate_hz, starting no later than the output started, waiting up to timeout_s; the
    // result's frames/status/message as for read(). Both throw DeviceError when unsupported
    // or when the instrument reports an error (naming its native error text).
    virtual void play(std::span<const double> sin_v, std::span<const double> cos_v, double sample_rate_hz, bool cyclic) {
        (void)sin_v; (void)cos_v; (void)sample_rate_hz; (void)cyclic;
        throw DeviceError(info().uri, "playing a waveform from memory is not supported by this device");
    }
    virtual StreamResult record(std::span<double> sin_v, std::span<double> cos_v, double sample_rate_hz, double timeout_s) {
        (void)sin_v; (void)cos_v; (void)sample_rate_hz; (void)timeout_s;
        throw DeviceError(info().uri, "recording a block is not supported by this device");
    }
    virtual void stop_output() {}

    // Step mode: set a static sin/cos pair, wait settle_s, read back (averaged).
    virtual StepResult step(double sin_v, double cos_v, double settle_s, int average) {
        (void)sin_v; (void)cos_v; (void)settle_s; (void)average;
        throw DeviceError(info().uri, "step mode is not supported by this device");
    }

private:
    friend std::unique_ptr<Device> open(const std::string& uri);
    // Released after the driver's own destructor has closed the device.
    std::shared_ptr<DeviceLock> lock_;
};

class DeviceLock {
public:
    // Takes the lock on key (a file in lock_dir()), or throws DeviceError(device, "busy: ...").
    // A key this thread already holds is shared (a run that opens one instrument twice);
    // another thread of this process holding it is busy too (two runs in one service).
    static std::shared_ptr<DeviceLock> acquire(const std::string& key, const std::string& device);
    // The resolved device a URI names, the same for every spelling of it (127.0.0.1 and 127.1,
    // a symlink and its pty), empty for devices nothing else can own (loopback, capture).
    // Modbus TCP: resolved address, port and unit; serial: the real path; USB: VID:PID (every
    // board of it: a URI without a serial opens the first one found); SCPI over TCP: resolved address and port.
    static std::string key_for(const std::string& uri);
    // $FRINGE_LOCK_DIR, else /run/lock/fringe when /run/lock is writable, else /tmp/fringe-locks:
    // machine-wide, so runs with different data directories and users still meet.
    static std::string lock_dir();
    ~DeviceLock();
    DeviceLock(const DeviceLock&) = delete;
    DeviceLock& operator=(const DeviceLock&) = delete;
    const std::string& key() const { return key_; }

private:
    DeviceLock(std::string key, int fd) : key_(std::move(key)), fd_(fd) {}
    std::string key_;
    int fd_ = -1;
};

struct DriverInfo {
    std::string scheme;  // URI scheme: "loopback", "capture", ...
    std::string summary;
    std::vector<ParamInfo> settings;  // query parameters
    std::function<std::unique_ptr<Device>(const std::string& uri, const std::string& path, const nlohmann::json& settings)> open;
    // Devices of this driver that are reachable now, each {uri, description, board_id}
    // (SoapySDR's find); empty when the driver cannot discover (Modbus: give the address).
    std::function<std::vector<nlohmann::json>()> find;
};
void to_json(nlohmann::json& j, const DriverInfo& d);

const std::vector<DriverInfo>& drivers();
// Parses scheme:path?k=v&k=v, validates the query against the driver's settings (errors name
// "device.<key>"), opens it. Throws ConfigError for a bad URI, DeviceError for a device fault.
std::unique_ptr<Device> open(const std::string& uri);
// The same parsing and validation without opening anything.
struct UriParts {
    std::string scheme, path;
    nlohmann::json settings;
};
UriParts check_uri(const std::string& uri);

}  // namespace fringe::dev
