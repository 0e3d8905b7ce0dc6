// Where a run's input frames come from, each with its truth (docs/architecture.md): the seam
// between the run engine and the kinds of device. A source writes what the device needs
// (generated signals), reads what it returns, and pairs every input frame with the truth of
// the sample it shows. Each source drives one kind of capability port (drivers/device.hpp),
// and the source is chosen from the ports the device has:
//   StepSource    a StepPort (Modbus boards): one static pair per frame, settle, read back
//   StreamSource  a StreamPort (loopback, USB): write ahead, read, align truth for the
//                 device's declared latency; generate_ahead() makes the next block beforehand
//   ReplaySource  a ReplayPort (capture replay): frames and truth from the file
//   InstrumentSource  a PlayPort plays the whole signal from a generator's memory, a
//                 RecordPort on its own clock records it; truth is aligned from the signals
//                 (server/analysis/align.*)
#pragma once

#include "drivers/device.hpp"
#include "server/engine/scenario.hpp"

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace fringe {

struct Frames {
    std::vector<double> t_s, sin_v, cos_v;
    std::vector<double> theta_true_rad, omega_true_rad_s;  // omega NaN where the source has no rate truth
    std::vector<std::uint8_t> truth_known;
    std::vector<double> dut_theta_rad;  // the DUT's own position (NaN: none); empty without a DUT
    std::size_t size() const { return t_s.size(); }
    void resize(std::size_t n, bool dut);
};

struct SourceStatus {
    bool ok = true;
    bool end = false;     // the source has no more frames (a capture's end)
    std::string error;    // when !ok: what failed, with the stream position
};

class FrameSource {
public:
    virtual ~FrameSource() = default;
    // Up to max frames into out (resized to what was delivered). Device faults on the stream
    // path come back as a status; configuration faults throw.
    virtual SourceStatus next(std::size_t max, Frames& out) = 0;
    // Work for a later next() that a source can do beside next() on another thread: the stream
    // source generates the signal its next call will write. The run engine calls it once with
    // each next(), in the same step (the two touch separate state); frames are the same whether
    // or not it is called.
    virtual void generate_ahead() {}
    virtual void stop() {}
    // The truth alignment (report "alignment"; docs/alignment.md), null for sources without one.
    virtual nlohmann::json alignment() const { return nullptr; }
};

// One device: play+record ports (one instrument), else step without streams, else streams,
// else a replay. Throws std::runtime_error for a device with none of these (or only half of
// a generator/digitizer pair), naming it.
std::unique_ptr<FrameSource> make_frame_source(const Scenario& sc, dev::Device& device, const dev::DeviceInfo& info,
                                               std::size_t block);
// A generator (output: its PlayPort) and a digitizer (input: its RecordPort); they may be one
// device. Throws std::runtime_error naming the field whose device lacks its port.
std::unique_ptr<FrameSource> make_instrument_source(const Scenario& sc, dev::Device& output, dev::Device& input);

}  // namespace fringe
