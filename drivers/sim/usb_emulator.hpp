// An emulated fringe USB streaming board for CI, on libumockdev: a device description
// (descriptors for VID:PID, one vendor interface, bulk endpoints 0x01/0x81) and an ioctl
// handler that implements docs/usb-protocol.md with a simulated analog loopback. Its sample
// clock either keeps real time (a free-running board: a host that falls behind loses IN frames,
// one that writes too late underflows) or is paced by the host (each IN frame is made when the
// host has sent its samples and has a transfer waiting: no timing, so tests of everything else
// are deterministic). The process must run under umockdev's preload
// (LD_PRELOAD=libumockdev-preload.so.0); libusb in the same process then sees the board.
// Fault injection: IN stall, the board going silent (timeout), dropped frames, unplug.
#pragma once

#include "drivers/usb_protocol.hpp"

#include <cstdint>
#include <memory>
#include <string>

namespace fringe::dev {

struct UsbEmulatorOptions {
    std::uint16_t vid = usbp::kTestVid, pid = usbp::kTestPid;
    std::string serial = "SIM0001";
    int adc_bits = 16;        // the loopback's ADC (on the int16 sample codes)
    double noise_v = 0.0;     // analog noise, V rms
    double range_v = 1.25;
    std::uint32_t max_rate_hz = 10000000;
    long long stall_after = -1;       // IN frames produced, then the IN endpoint stalls
    long long silent_after = -1;      // IN frames produced, then the board stops producing
    long long drop_at = -1;           // first IN frame lost on the board (never sent)
    long long drop_count = 1;
    long long unplug_after = -1;      // IN frames produced, then the board disappears
    std::uint64_t seed = 1;
    enum class Clock { Realtime, Paced };
    // Default: $FRINGE_USB_EMULATOR_CLOCK ("realtime" or "paced"), else realtime.
    Clock clock = default_clock();
    // A real-time clock runs at this fraction of real time (sanitizer builds are ~20x slower
    // hosts). Default: $FRINGE_USB_EMULATOR_TIME_SCALE, else 1.
    double time_scale = default_time_scale();
    static double default_time_scale();
    static Clock default_clock();
};

// "key=value,key=value" (the keys above); throws std::invalid_argument naming a bad key.
UsbEmulatorOptions parse_usb_emulator_options(const std::string& spec);

class UsbEmulator {
public:
    explicit UsbEmulator(UsbEmulatorOptions o);  // throws std::runtime_error outside umockdev's preload
    ~UsbEmulator();
    UsbEmulator(const UsbEmulator&) = delete;
    UsbEmulator& operator=(const UsbEmulator&) = delete;
    void unplug();  // now: pending and later transfers fail with ENODEV
    usbp::Status status() const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace fringe::dev
