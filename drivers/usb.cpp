// USB streaming boards (docs/usb-protocol.md) over libusb-1.0: vendor control requests for
// info, rate, start, stop, status; bulk OUT frames of DAC samples and bulk IN frames of ADC
// samples with sequence numbers, several asynchronous transfers in flight each way, sized
// from the sample rate. Sample loss is counted exactly from the IN sequence numbers; the
// board's underflow flag, stalls, timeouts and unplugging become stream statuses, never
// silence. Native errors keep libusb's names.
#include "device.hpp"
#include "signal_gen/base/config.hpp"
#include "usb_protocol.hpp"

#include <libusb.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <deque>
#include <memory>
#include <string>
#include <vector>

namespace fringe::dev {

namespace {

using clk = std::chrono::steady_clock;

std::string usb_err(int rc) { return std::string(libusb_error_name(rc)) + " (" + libusb_strerror(static_cast<libusb_error>(rc)) + ")"; }

class UsbDevice final : public Device, public StreamPort {
public:
    UsbDevice(const std::string& uri, const std::string& path, const nlohmann::json& s) : uri_(uri) {
        const Params p(s);
        unsigned vid = 0, pid = 0;
        if (path.empty()) {
            vid = usbp::kTestVid;
            pid = usbp::kTestPid;
        } else if (std::sscanf(path.c_str(), "%x:%x", &vid, &pid) != 2 || vid > 0xffff || pid > 0xffff) {
            throw ConfigError("device", "usb: expects usb:VID:PID in hex (e.g. usb:1209:ec01), got 'usb:" + path + "'");
        }
        want_serial_ = p.string("serial");
        transfers_ = static_cast<int>(p.integer("transfers"));
        frame_samples_setting_ = static_cast<int>(p.integer("frame_samples"));
        timeout_ms_ = static_cast<int>(p.integer("timeout_ms"));
        char id[16];
        std::snprintf(id, sizeof id, "%04x:%04x", vid, pid);
        vidpid_ = id;
        if (const int rc = libusb_init(&ctx_); rc != 0) throw DeviceError(uri_, "libusb_init: " + usb_err(rc));
        libusb_device** list = nullptr;
        const auto n = libusb_get_device_list(ctx_, &list);
        std::string seen;
        for (ssize_t i = 0; i < n && !h_; ++i) {
            libusb_device_descriptor d{};
            if (libusb_get_device_descriptor(list[i], &d) != 0 || d.idVendor != vid || d.idProduct != pid) continue;
            libusb_device_handle* h = nullptr;
            if (const int rc = libusb_open(list[i], &h); rc != 0) {
                seen += " " + vidpid_ + ": open: " + usb_err(rc) + ";";
                continue;
            }
            usbp::Info info{};
            const int got = libusb_control_transfer(h, 0xC0, usbp::GetInfo, 0, 0, reinterpret_cast<unsigned char*>(&info), sizeof info, 1000);
            const std::string serial(info.serial, strnlen(info.serial, sizeof info.serial));
            if (got != static_cast<int>(sizeof info) || info.protocol != usbp::kProtocolVersion) {
                seen += " " + vidpid_ + ": GET_INFO " + (got < 0 ? usb_err(got) : "short or wrong protocol") + ";";
                libusb_close(h);
                continue;
            }
            if (!want_serial_.empty() && serial != want_serial_) {
                seen += " serial " + serial + ";";
                libusb_close(h);
                continue;
            }
            h_ = h;
            info_ = info;
        }
        libusb_free_device_list(list, 1);
        if (!h_) {
            libusb_exit(ctx_);
            ctx_ = nullptr;
            throw DeviceError(uri_, "no fringe USB board " + vidpid_ + (want_serial_.empty() ? "" : " with serial " + want_serial_) + " found" +
                                        (seen.empty() ? "" : ":" + seen));
        }
        if (const int rc = libusb_claim_interface(h_, usbp::kInterface); rc != 0) {
            libusb_close(h_);
            libusb_exit(ctx_);
            ctx_ = nullptr;
            h_ = nullptr;
            throw DeviceError(uri_, "claim interface 0: " + usb_err(rc));
        }
        range_v_ = info_.range_mv / 1000.0;
        name_ = std::string(info_.name, strnlen(info_.name, sizeof info_.name));
        serial_ = std::string(info_.serial, strnlen(info_.serial, sizeof info_.serial));
    }

    ~UsbDevice() override {
        if (running_) stop_quietly();
        for (auto& x : xfers_) libusb_free_transfer(x->t);
        if (h_) {
            libusb_release_interface(h_, usbp::kInterface);
            libusb_close(h_);
        }
        if (ctx_) libusb_exit(ctx_);
    }

    // Streams only: no step mode, no generator memory, no block recording.
    StreamPort* stream() override { return this; }

    DeviceInfo describe() const override {
        DeviceInfo i;
        i.driver = "usb";
        i.uri = uri_;
        i.description = name_ + " (USB " + vidpid_ + ", " + std::to_string(info_.adc_bits) + "-bit ADC, " + std::to_string(info_.dac_bits) + "-bit DAC)";
        i.board_id = name_ + "#" + serial_;
        // A board whose IN frames carry DUT words (docs/usb-protocol.md) does not declare a DUT
        // position: the stream port delivers the sin/cos pairs only, and a "dut" lane would
        // have nothing to score. board_dut_words in settings says what the board sends.
        i.dut_position = false;
        i.settings = {{"serial", serial_}, {"transfers", transfers_}, {"frame_samples", frame_samples_ ? frame_samples_ : frame_samples_setting_}, {"timeout_ms", timeout_ms_},
                      {"adc_bits", info_.adc_bits}, {"dac_bits", info_.dac_bits}, {"range_v", range_v_}, {"max_rate_hz", info_.max_rate_hz},
                      {"board_dut_words", (info_.flags & 1) != 0}};
        i.converter.known = true;
        i.converter.adc_bits = info_.adc_bits;
        i.converter.dac_bits = info_.dac_bits;
        i.converter.adc_range_v = i.converter.dac_range_v = range_v_;
        i.converter.note = "the board reports its converters' bits and range, not its analog noise: quantisation only";
        i.converter.added_noise_v = i.converter.independent_noise_v();
        return i;
    }

    void start(double fs) override {
        if (running_) throw DeviceError(uri_, "already streaming");
        if (fs <= 0 || fs > info_.max_rate_hz) throw DeviceError(uri_, "sample rate " + std::to_string(fs) + " Hz outside 0.." + std::to_string(info_.max_rate_hz));
        // Frames of about 10 ms: few enough transfers per second, short enough latency.
        frame_samples_ = frame_samples_setting_ > 0 ? frame_samples_setting_ : static_cast<int>(std::clamp(fs / 100.0, 64.0, 16384.0));
        frame_samples_ = std::min<int>(frame_samples_, info_.max_frame_samples);
        usbp::RateRequest rr{static_cast<std::uint32_t>(std::lround(fs)), static_cast<std::uint16_t>(frame_samples_), 0};
        control_out(usbp::SetRate, &rr, sizeof rr, "SET_RATE");
        dut_ = (info_.flags & 1) != 0;
        for (auto& x : xfers_) libusb_free_transfer(x->t);
        xfers_.clear();
        const std::size_t in_bytes = usbp::frame_bytes(static_cast<std::size_t>(frame_samples_), dut_);
        const std::size_t out_bytes = usbp::frame_bytes(static_cast<std::size_t>(frame_samples_), false);
        for (int k = 0; k < 2 * transfers_; ++k) {
            auto x = std::make_unique<Xfer>();
            x->self = this;
            x->in = k < transfers_;
            x->buf.resize(x->in ? in_bytes : out_bytes);
            x->t = libusb_alloc_transfer(0);
            xfers_.push_back(std::move(x));
        }
        in_s_.clear();
        in_c_.clear();
        next_in_seq_ = 0;
        out_seq_ = 0;
        delivered_ = 0;
        events_.clear();
        ended_ = false;
        out_codes_.clear();
        fault_.clear();
        control_out(usbp::Start, nullptr, 0, "START");
        running_ = true;
        for (auto& x : xfers_)
            if (x->in) submit(*x);
    }

    // Whole frames only: a short frame tells the board the output has ended (end_of_output).
    StreamResult write(std::span<const double> s, std::span<const double> c) override {
        if (!running_) return {StreamStatus::Error, 0, 0, 0, "not streaming (start first)"};
        if (ended_) return {StreamStatus::Error, 0, 0, 0, "write after end_of_output"};
        for (std::size_t i = 0; i < s.size(); ++i) {
            out_codes_.push_back(to_code(s[i]));
            out_codes_.push_back(to_code(c[i]));
        }
        const auto fs = static_cast<std::size_t>(frame_samples_);
        while (out_codes_.size() >= 2 * fs) {
            if (auto r = send_frame(fs); r.status != StreamStatus::Ok) return r;
        }
        return {StreamStatus::Ok, s.size(), 0, 0, ""};
    }

    void end_of_output() override {
        if (!running_ || ended_) return;
        ended_ = true;
        if (!out_codes_.empty()) send_frame(out_codes_.size() / 2);
    }

    StreamResult read(std::span<double> s, std::span<double> c, int timeout_ms) override {
        if (!running_) return {StreamStatus::Error, 0, 0, 0, "not streaming (start first)"};
        const auto deadline = clk::now() + std::chrono::milliseconds(std::max(timeout_ms, 0));
        for (;;) {
            // Events are reported at the stream position where they happened: samples that
            // arrived before a loss or an underflow are delivered first.
            if (!events_.empty() && events_.front().pos == delivered_) {
                const Event e = events_.front();
                events_.pop_front();
                return {e.status, 0, e.pos, e.dropped, e.message};
            }
            if (!in_s_.empty()) break;
            if (!fault_.empty()) return {fault_status_, 0, delivered_, 0, fault_};
            if (clk::now() >= deadline) return {StreamStatus::Timeout, 0, delivered_, 0, "no IN frame within " + std::to_string(timeout_ms) + " ms"};
            pump(10);
        }
        std::size_t n = std::min(s.size(), in_s_.size());
        if (!events_.empty()) n = std::min<std::size_t>(n, static_cast<std::size_t>(events_.front().pos - delivered_));
        const double q = range_v_ / 32768.0;
        for (std::size_t i = 0; i < n; ++i) {
            s[i] = in_s_[i] * q;
            c[i] = in_c_[i] * q;
        }
        in_s_.erase(in_s_.begin(), in_s_.begin() + static_cast<std::ptrdiff_t>(n));
        in_c_.erase(in_c_.begin(), in_c_.begin() + static_cast<std::ptrdiff_t>(n));
        StreamResult r{StreamStatus::Ok, n, delivered_, 0, ""};
        delivered_ += n;
        return r;
    }

    void stop() override {
        if (running_) stop_quietly();
    }

private:
    StreamResult send_frame(std::size_t n) {
        const auto deadline = clk::now() + std::chrono::milliseconds(timeout_ms_);
        for (;;) {
            if (!fault_.empty()) return {fault_status_, 0, 0, 0, fault_};
            Xfer* free = nullptr;
            for (auto& x : xfers_)
                if (!x->in && !x->busy) { free = x.get(); break; }
            if (free) {
                usbp::FrameHeader hdr{usbp::kMagic, out_seq_++, static_cast<std::uint16_t>(n), 0, 0};
                std::memcpy(free->buf.data(), &hdr, sizeof hdr);
                std::memcpy(free->buf.data() + sizeof hdr, out_codes_.data(), 4 * n);
                out_codes_.erase(out_codes_.begin(), out_codes_.begin() + static_cast<std::ptrdiff_t>(2 * n));
                free->len = static_cast<int>(usbp::frame_bytes(n, false));
                submit(*free);
                if (!fault_.empty()) return {fault_status_, 0, 0, 0, fault_};
                return {StreamStatus::Ok, n, 0, 0, ""};
            }
            if (clk::now() > deadline)
                return {StreamStatus::Timeout, 0, 0, 0, "no OUT transfer completed within " + std::to_string(timeout_ms_) + " ms (the board stopped taking samples)"};
            pump(10);
        }
    }

    struct Xfer {
        UsbDevice* self = nullptr;
        libusb_transfer* t = nullptr;
        std::vector<unsigned char> buf;
        int len = 0;
        bool in = false, busy = false;
    };

    std::int16_t to_code(double v) const {
        const double code = std::nearbyint(v / range_v_ * 32768.0);
        return static_cast<std::int16_t>(std::clamp(std::isfinite(code) ? code : 0.0, -32768.0, 32767.0));
    }

    void control_out(std::uint8_t req, const void* data, std::uint16_t len, const char* what) {
        const int rc = libusb_control_transfer(h_, 0x40, req, 0, 0, static_cast<unsigned char*>(const_cast<void*>(data)), len, 1000);
        if (rc < 0) throw DeviceError(uri_, std::string(what) + ": " + usb_err(rc));
    }

    void submit(Xfer& x) {
        if (x.in) {
            libusb_fill_bulk_transfer(x.t, h_, usbp::kEpIn, x.buf.data(), static_cast<int>(x.buf.size()), &UsbDevice::on_done, &x, 0);
        } else {
            libusb_fill_bulk_transfer(x.t, h_, usbp::kEpOut, x.buf.data(), x.len, &UsbDevice::on_done, &x, static_cast<unsigned>(timeout_ms_));
        }
        const int rc = libusb_submit_transfer(x.t);
        if (rc != 0) {
            fail(StreamStatus::Error, std::string("submit ") + (x.in ? "IN" : "OUT") + ": " + (rc == LIBUSB_ERROR_NO_DEVICE ? "device unplugged, " : "") + usb_err(rc));
            return;
        }
        x.busy = true;
    }

    void fail(StreamStatus st, const std::string& msg) {
        if (fault_.empty()) {
            fault_ = msg;
            fault_status_ = st;
        }
    }

    static void LIBUSB_CALL on_done(libusb_transfer* t) {
        auto* x = static_cast<Xfer*>(t->user_data);
        x->busy = false;
        x->self->completed(*x);
    }

    void completed(Xfer& x) {
        const auto* t = x.t;
        const char* ep = x.in ? "IN endpoint 0x81" : "OUT endpoint 0x01";
        switch (t->status) {
            case LIBUSB_TRANSFER_COMPLETED: break;
            case LIBUSB_TRANSFER_CANCELLED: return;
            case LIBUSB_TRANSFER_STALL: fail(StreamStatus::Error, std::string("stall on ") + ep); return;
            case LIBUSB_TRANSFER_NO_DEVICE: fail(StreamStatus::Error, "device unplugged (" + std::string(ep) + ")"); return;
            case LIBUSB_TRANSFER_TIMED_OUT: fail(StreamStatus::Timeout, std::string("transfer timed out on ") + ep); return;
            default: fail(StreamStatus::Error, std::string("transfer error on ") + ep + ": " + libusb_error_name(t->status)); return;
        }
        if (!x.in) return;
        if (t->actual_length < static_cast<int>(sizeof(usbp::FrameHeader))) {
            fail(StreamStatus::Error, "short IN frame (" + std::to_string(t->actual_length) + " bytes)");
            return;
        }
        usbp::FrameHeader h;
        std::memcpy(&h, x.buf.data(), sizeof h);
        const bool dut = (h.flags & usbp::kFlagDut) != 0;
        if (h.magic != usbp::kMagic || static_cast<std::size_t>(t->actual_length) < usbp::frame_bytes(h.samples, dut)) {
            fail(StreamStatus::Error, "malformed IN frame (seq " + std::to_string(h.seq) + ")");
            return;
        }
        const std::uint64_t pos = delivered_ + in_s_.size();  // stream index of this frame's first sample
        if (h.seq != next_in_seq_) {
            const std::uint32_t gap = h.seq - next_in_seq_;
            const std::uint64_t lost = static_cast<std::uint64_t>(gap) * static_cast<std::uint64_t>(frame_samples_);
            events_.push_back({pos, StreamStatus::Overflow, lost,
                               std::to_string(lost) + " samples lost: IN frames " + std::to_string(next_in_seq_) +
                                   (gap > 1 ? ".." + std::to_string(h.seq - 1) : "") + " never arrived"});
        }
        next_in_seq_ = h.seq + 1;
        if (h.flags & usbp::kFlagUnderflow)
            events_.push_back({pos, StreamStatus::Underflow, 0, "the board ran out of DAC samples (IN frame " + std::to_string(h.seq) + " flagged underflow)"});
        const auto* p = x.buf.data() + sizeof h;
        for (std::size_t i = 0; i < h.samples; ++i) {
            std::int16_t a, b;
            usbp::get_pair(p, i, a, b);
            in_s_.push_back(a);
            in_c_.push_back(b);
        }
        if (running_) submit(x);
    }

    void pump(int ms) {
        timeval tv{0, ms * 1000};
        const int rc = libusb_handle_events_timeout_completed(ctx_, &tv, nullptr);
        if (rc != 0 && rc != LIBUSB_ERROR_INTERRUPTED) fail(StreamStatus::Error, "libusb events: " + usb_err(rc));
    }

    void stop_quietly() {
        running_ = false;
        if (fault_.empty() || fault_status_ != StreamStatus::Error) {
            const int rc = libusb_control_transfer(h_, 0x40, usbp::Stop, 0, 0, nullptr, 0, 1000);
            (void)rc;  // a board that is gone cannot be stopped; the transfers below still end
        }
        for (auto& x : xfers_)
            if (x->busy) libusb_cancel_transfer(x->t);
        const auto until = clk::now() + std::chrono::seconds(1);
        while (clk::now() < until && std::any_of(xfers_.begin(), xfers_.end(), [](const auto& x) { return x->busy; })) pump(10);
    }

    std::string uri_, vidpid_, want_serial_, name_, serial_;
    libusb_context* ctx_ = nullptr;
    libusb_device_handle* h_ = nullptr;
    usbp::Info info_{};
    double range_v_ = 1.25;
    int transfers_ = 8, frame_samples_setting_ = 0, frame_samples_ = 0, timeout_ms_ = 1000;
    bool dut_ = false, running_ = false;
    std::vector<std::unique_ptr<Xfer>> xfers_;
    std::deque<std::int16_t> in_s_, in_c_;
    std::vector<std::int16_t> out_codes_;  // interleaved sin, cos codes not yet sent as a whole frame
    bool ended_ = false;
    std::uint32_t next_in_seq_ = 0, out_seq_ = 0;
    std::uint64_t delivered_ = 0;
    struct Event {
        std::uint64_t pos;  // stream index where it happened
        StreamStatus status;
        std::uint64_t dropped;
        std::string message;
    };
    std::deque<Event> events_;
    std::string fault_;
    StreamStatus fault_status_ = StreamStatus::Ok;
};

}  // namespace

void register_usb(std::vector<DriverInfo>& r) {
    DriverInfo d;
    d.scheme = "usb";
    d.summary = "USB streaming board (docs/usb-protocol.md) over libusb: usb:VID:PID[?serial=...]; default VID:PID 1209:ec01";
    d.settings = {
        {"serial", "", ParamType::String, "", -kInf, kInf, {}, "only the board with this serial (from GET_INFO); empty: the first found"},
        {"transfers", "", ParamType::Integer, 16, 2, 64, {}, "bulk transfers in flight each way (16 x 10 ms frames: 160 ms of slack for a busy host)"},
        {"frame_samples", "samples", ParamType::Integer, 0, 0, 16384, {}, "sample pairs per frame (0: about 10 ms at the stream rate)"},
        {"timeout_ms", "ms", ParamType::Integer, 1000, 10, 60000, {}, "how long a write may wait for the board to take samples"},
    };
    d.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        return std::make_unique<UsbDevice>(uri, path, s);
    };
    // Boards with the default VID:PID that answer GET_INFO.
    d.find = []() {
        std::vector<nlohmann::json> out;
        libusb_context* ctx = nullptr;
        if (libusb_init(&ctx) != 0) return out;
        libusb_device** list = nullptr;
        const auto n = libusb_get_device_list(ctx, &list);
        for (ssize_t i = 0; i < n; ++i) {
            libusb_device_descriptor dd{};
            if (libusb_get_device_descriptor(list[i], &dd) != 0 || dd.idVendor != usbp::kTestVid || dd.idProduct != usbp::kTestPid) continue;
            libusb_device_handle* h = nullptr;
            if (libusb_open(list[i], &h) != 0) continue;
            usbp::Info info{};
            if (libusb_control_transfer(h, 0xC0, usbp::GetInfo, 0, 0, reinterpret_cast<unsigned char*>(&info), sizeof info, 1000) == static_cast<int>(sizeof info)) {
                const std::string name(info.name, strnlen(info.name, sizeof info.name)), serial(info.serial, strnlen(info.serial, sizeof info.serial));
                out.push_back({{"uri", "usb:1209:ec01?serial=" + serial}, {"description", name + " (USB)"}, {"board_id", name + "#" + serial}});
            }
            libusb_close(h);
        }
        libusb_free_device_list(list, 1);
        libusb_exit(ctx);
        return out;
    };
    r.push_back(std::move(d));
}

}  // namespace fringe::dev
