// The Device interface (README "Bench drivers"): one interface for the simulated loopback,
// capture replay, Modbus boards, USB streaming boards and SCPI instruments, opened by URI
// (`loopback:?adc_bits=12&noise_v=1e-4`, `capture:/path/x.fcap`, `modbus+tcp://...`,
// `usb:1209:ec01`) and asked for what it can do one capability port at a time (stream, step,
// play, record, replay; docs/architecture.md "Device capabilities"): a capability it lacks is
// a null port. Settings describe themselves. Configuration and control throw DeviceError
// naming the device and the native cause; the stream path returns a status with exact counts
// and never throws per block. Sample loss is never silent.
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
    // The capability ports the device has (Device::info fills them from the ports; a driver
    // never sets them): stream(), step(), player(), recorder(), replay() not null.
    bool streaming = false;   // StreamPort: output and input streams
    bool step_mode = false;   // StepPort: static pair, settle, read back
    bool can_play = false;    // PlayPort: a generator playing a block from its memory
    bool can_record = false;  // RecordPort: a digitizer recording a block
    bool replay = false;      // ReplayPort: an input-only source (capture replay)
    bool readout = false;     // ReadoutPort: a DUT's own position words (a scenario's device.dut)
    // The device reads out a DUT's own position (a step's StepResult::dut_theta_rad, or a
    // replay's ABZ lines): declared by the driver, which delivers it through those ports.
    bool dut_position = false;
    int latency_samples = 0;  // known input delay relative to the output, samples
    // Blocks of output a stream source keeps written ahead of the input it reads: a real-time
    // board must never run dry while the host reads (4); a simulated device waits for nobody (1:
    // the run's working set, and its first-touch page faults, shrink by three blocks).
    int output_ahead_blocks = 4;
    nlohmann::json settings = nlohmann::json::object();  // resolved settings
    ConverterInfo converter;
    // Instrument mode (issue 14): such devices run on their own clocks with an unknown delay
    // between output and input: the run engine aligns truth from the signals
    // (server/analysis/align.*) before scoring. own_clock: output and input are not
    // sample-locked (the engine must estimate delay, clock ratio, gain and offset).
    bool own_clock = false;
    std::size_t max_play_samples = 0;  // generator memory per channel (PlayPort::memory_samples; 0: unlimited)
    // The ports' names, in a fixed order ("stream", "step", "play", "record", "replay").
    std::vector<std::string> ports() const;
};
void to_json(nlohmann::json& j, const DeviceInfo& d);
void to_json(nlohmann::json& j, const ConverterInfo& c);

struct StepResult {
    double sin_v = 0, cos_v = 0;         // measured (averaged) ADC pair
    std::optional<double> dut_theta_rad; // the DUT's own interpolated position, if it has one
};

// ---- Capability ports -------------------------------------------------------------------
// A device is asked for each capability it may have (Device::stream(), step(), player(),
// recorder(), replay()); one it does not have is a null port, never a method that does
// nothing or an error at call time. The run engine chooses its frame source from the ports
// that exist (server/engine/frame_source.cpp).

// Output and input streams at one sample rate, sample-locked (loopback, USB boards).
class StreamPort {
public:
    virtual ~StreamPort() = default;
    virtual void start(double sample_rate_hz) = 0;
    // Queue output frames (V). Non-blocking for simulated devices.
    virtual StreamResult write(std::span<const double> sin_v, std::span<const double> cos_v) = 0;
    // The last write has been made. A device that sends whole frames (USB) sends the
    // remainder now as the stream's final, short frame; others have nothing to do.
    virtual void end_of_output() {}
    // Read up to sin_v.size() input frames (V).
    virtual StreamResult read(std::span<double> sin_v, std::span<double> cos_v, int timeout_ms) = 0;
    virtual void stop() = 0;
};

// Step mode (Modbus boards, loopback): set a static sin/cos pair, wait settle_s (< 0: the
// device's own), read back averaged over `average` readings (<= 0: the device's own).
struct BoardProfile;
enum class RegTable;

// Raw register access to a Modbus board (its profile's registers by address), under the driver's
// retry policy and error naming; what writing a correction to a board uses (modbus_board.hpp).
class RegisterPort {
public:
    virtual ~RegisterPort() = default;
    virtual const BoardProfile& board() const = 0;
    // function 16: one request for all the words; 6: one request per word. `what` names the
    // request in errors ("write correction_table_rad[0..61] @200+62").
    virtual void write_words(int address, std::span<const std::uint16_t> words, int function, const std::string& what) = 0;
    virtual void read_words(RegTable table, int address, int count, std::uint16_t* dst, const std::string& what) = 0;
};

class StepPort {
public:
    virtual ~StepPort() = default;
    virtual StepResult measure(double sin_v, double cos_v, double settle_s, int average) = 0;
};

// A waveform generator: upload both channels (V) at sample_rate_hz and start the output;
// cyclic repeats the block until stop_output, else it plays once. Throws DeviceError when
// the instrument reports an error (naming its native error text).
class SequencePort;
class PlayPort {
public:
    virtual ~PlayPort() = default;
    virtual void play(std::span<const double> sin_v, std::span<const double> cos_v, double sample_rate_hz, bool cyclic) = 0;
    virtual void stop_output() = 0;
    virtual std::size_t memory_samples() const = 0;  // per channel; 0: unlimited
    // Segmented playback of a signal longer than the memory (SequencePort); null when the
    // generator has none, and then sequence_refusal() says why (instrument and mode).
    virtual SequencePort* sequencer() { return nullptr; }
    virtual std::string sequence_refusal() const { return "it has no segmented (sequence or streaming) playback"; }
};

// What a generator's segmented playback allows (docs/bench.md "Segmented playback").
struct SequenceLimits {
    std::size_t max_segments = 0;         // segments in one playback
    std::size_t min_segment_samples = 1;  // per channel; the last segment too
    std::size_t max_segment_samples = 0;  // per channel (at most the memory)
};

// A generator playing one signal longer than its memory as segments back to back from one
// start (armed and triggered as PlayPort::play, played once), sample-continuous: no gap and no
// repeated sample at a join. segment_samples per segment, the last one shorter; stop with
// PlayPort::stop_output. Throws DeviceError when the limits are broken or the instrument fails.
class SequencePort {
public:
    virtual ~SequencePort() = default;
    virtual SequenceLimits sequence_limits() const = 0;
    virtual void play_segments(std::span<const double> sin_v, std::span<const double> cos_v, std::size_t segment_samples, double sample_rate_hz) = 0;
};

// A digitizer or scope: acquire up to sin_v.size() input frames at (nominally)
// sample_rate_hz, starting no later than the output started, waiting up to timeout_s; the
// result's frames/status/message as for StreamPort::read.
class RecordPort {
public:
    virtual ~RecordPort() = default;
    virtual StreamResult record(std::span<double> sin_v, std::span<double> cos_v, double sample_rate_hz, double timeout_s) = 0;
};

// An input-only source (capture replay): frames with the truth they carry.
class ReplayPort {
public:
    virtual ~ReplayPort() = default;
    // Checks the source against the run's sample rate (throws DeviceError on a mismatch).
    virtual void start(double sample_rate_hz) = 0;
    // Up to sin_v.size() frames; 0 frames with status Ok is the source's end.
    virtual StreamResult read(std::span<double> sin_v, std::span<double> cos_v, int timeout_ms) = 0;
    // The truth of the frames of the last read; false when the source carries none.
    virtual bool last_truth(std::span<double> theta_rad, std::span<double> omega_rad_s) = 0;
    // The DUT's position (rad, NaN where it has none) for the frames of the last read, from a
    // DUT read out alongside (ABZ lines in a capture, DeviceInfo::dut_position); false when
    // the source has none. What the readout counted (edges, illegal transitions, index
    // checks) is dut_readout(), null without one.
    virtual bool last_dut(std::span<double> theta_rad) = 0;
    virtual nlohmann::json dut_readout() const = 0;
};

// A DUT's own answer read out beside the run (a scenario's "device.dut", drivers/readout.cpp,
// docs/dut-readouts.md): its position words, each time-stamped at its latch instant on the
// readout's clock. The run maps that clock to its own (readout_to_run_s) and scores every word
// once, against the truth at its latch instant.
struct PositionWordOut {
    double t_s = 0;          // latch instant, readout clock
    double theta_rad = 0;    // the DUT's electrical angle; NaN when the word is invalid
    bool valid = false;
};

class ReadoutPort {
public:
    virtual ~ReadoutPort() = default;
    // Starts acquiring (a live readout starts its instrument here). Throws DeviceError.
    virtual void start() = 0;
    // The words latched at or before up_to_s (readout clock), in latch order, appended to out;
    // a live readout waits up to timeout_ms for its clock to pass up_to_s. status Ok with
    // frames = words appended; Timeout (nothing new in time: a frozen readout); Error (gone,
    // unreadable; message says why). After the source's end, Ok with 0 words.
    virtual StreamResult read_words(double up_to_s, std::vector<PositionWordOut>& out, int timeout_ms) = 0;
    // Words per second the readout delivers (configured, or measured from its first words).
    virtual double word_rate_hz() const = 0;
    // Offset from the readout's clock to the run's: t_run = t_readout + readout_to_run_s.
    virtual double readout_to_run_s() const = 0;
    // How long a live readout may stay silent before the run calls it frozen (read_words' timeout).
    virtual double stall_s() const = 0;
    // What the readout counted (protocol, settings, words, wire errors by cause).
    virtual nlohmann::json stats() const = 0;
    virtual void stop() = 0;
};

class Device {
public:
    virtual ~Device() = default;
    // What the driver describes (describe()), with the capability flags set from the ports.
    DeviceInfo info() const;

    // The run's cancel flag (may be null): a device that waits (retries, reconnects, settles)
    // checks it and throws Cancelled. Devices that never wait long ignore it.
    virtual void set_cancel(const std::atomic<bool>* cancel) { (void)cancel; }

    // The capability ports; null where the device does not have the capability.
    virtual StreamPort* stream() { return nullptr; }
    virtual StepPort* step() { return nullptr; }
    virtual PlayPort* player() { return nullptr; }
    virtual RecordPort* recorder() { return nullptr; }
    virtual ReplayPort* replay() { return nullptr; }
    virtual RegisterPort* registers() { return nullptr; }
    virtual ReadoutPort* readout() { return nullptr; }

protected:
    virtual DeviceInfo describe() const = 0;

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

// A number in a message: %.10g (no trailing zeros, whole numbers without a point).
std::string num(double v);

}  // namespace fringe::dev
