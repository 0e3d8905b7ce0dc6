// The fringe USB streaming board protocol (docs/usb-protocol.md), shared by the libusb driver
// and the emulated board. All multi-byte fields are little-endian.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>

namespace fringe::dev::usbp {

constexpr std::uint16_t kTestVid = 0x1209, kTestPid = 0xec01;  // pid.codes test VID, fringe's default PID
constexpr std::uint8_t kInterface = 0;
constexpr std::uint8_t kEpOut = 0x01, kEpIn = 0x81;
constexpr std::uint16_t kProtocolVersion = 1;

// Vendor requests (bmRequestType 0xC0 device-to-host / 0x40 host-to-device, recipient device).
enum Request : std::uint8_t { GetInfo = 0x01, SetRate = 0x02, Start = 0x03, Stop = 0x04, GetStatus = 0x05 };

#pragma pack(push, 1)
struct Info {                     // GET_INFO, 64 bytes
    std::uint16_t protocol;       // kProtocolVersion
    std::uint16_t flags;          // bit 0: IN frames carry DUT position words
    std::uint8_t adc_bits, dac_bits;
    std::uint16_t range_mv;       // full scale +-range (DAC and ADC)
    std::uint32_t max_rate_hz;
    std::uint16_t max_frame_samples;
    std::uint16_t reserved;
    char name[32];
    char serial[16];
};
struct RateRequest {              // SET_RATE data, 8 bytes
    std::uint32_t rate_hz;
    std::uint16_t frame_samples;  // samples per frame, both directions
    std::uint16_t reserved;
};
struct Status {                   // GET_STATUS, 16 bytes
    std::uint32_t in_frames;      // IN frames produced since START (delivered or dropped)
    std::uint32_t in_dropped;     // IN frames the host had no transfer pending for
    std::uint32_t underflows;     // IN frames produced without enough OUT samples
    std::uint8_t running;
    std::uint8_t reserved[3];
};
struct FrameHeader {              // every bulk frame, both directions, 16 bytes
    std::uint32_t magic;          // kMagic
    std::uint32_t seq;            // per direction, from 0 at START; a gap is a lost frame
    std::uint16_t samples;        // sample pairs in this frame
    std::uint16_t flags;          // IN: bit 0 underflow (OUT data ran out for this frame), bit 1 DUT words follow
    std::uint32_t reserved;
};
#pragma pack(pop)
static_assert(sizeof(Info) == 64 && sizeof(RateRequest) == 8 && sizeof(Status) == 16 && sizeof(FrameHeader) == 16);

constexpr std::uint32_t kMagic = 0x474e5246;  // "FRNG"
constexpr std::uint16_t kFlagUnderflow = 1, kFlagDut = 2;
// Payload: samples x (int16 sin, int16 cos), then with kFlagDut samples x int32 DUT position
// (1/65536 of an electrical period).
inline std::size_t frame_bytes(std::size_t samples, bool dut) { return sizeof(FrameHeader) + samples * (4 + (dut ? 4 : 0)); }

// Sample pair i of a payload (little-endian int16 sin, cos), both ways.
inline void put_pair(std::uint8_t* payload, std::size_t i, std::int16_t sin_code, std::int16_t cos_code) {
    std::memcpy(payload + 4 * i, &sin_code, 2);
    std::memcpy(payload + 4 * i + 2, &cos_code, 2);
}
inline void get_pair(const std::uint8_t* payload, std::size_t i, std::int16_t& sin_code, std::int16_t& cos_code) {
    std::memcpy(&sin_code, payload + 4 * i, 2);
    std::memcpy(&cos_code, payload + 4 * i + 2, 2);
}

}  // namespace fringe::dev::usbp
