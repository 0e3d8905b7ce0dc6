#include "drivers/sim/usb_emulator.hpp"

#include <umockdev.h>

#include <linux/ioctl.h>
#include <linux/usbdevice_fs.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <mutex>
#include <random>
#include <stdexcept>
#include <vector>

namespace fringe::dev {

namespace {

using clk = std::chrono::steady_clock;

struct Urb {
    UMockdevIoctlData* urb = nullptr;  // struct usbdevfs_urb (resolved copy, synced back on reap)
    UMockdevIoctlData* buf = nullptr;  // its buffer
    usbdevfs_urb* u() const { return reinterpret_cast<usbdevfs_urb*>(urb->data); }
    void release() {
        if (buf) g_object_unref(buf);
        if (urb) g_object_unref(urb);
        buf = urb = nullptr;
    }
};

std::string hex(const std::vector<std::uint8_t>& b) {
    std::string s;
    char t[3];
    for (auto x : b) {
        std::snprintf(t, sizeof t, "%02x", x);
        s += t;
    }
    return s;
}

}  // namespace

double UsbEmulatorOptions::default_time_scale() {
    const char* e = std::getenv("FRINGE_USB_EMULATOR_TIME_SCALE");
    const double v = e ? std::atof(e) : 1.0;
    return v > 0 && v <= 1 ? v : 1.0;
}

namespace {
UsbEmulatorOptions::Clock parse_clock(const std::string& v) {
    if (v == "realtime") return UsbEmulatorOptions::Clock::Realtime;
    if (v == "paced") return UsbEmulatorOptions::Clock::Paced;
    throw std::invalid_argument("clock");
}
}  // namespace

UsbEmulatorOptions::Clock UsbEmulatorOptions::default_clock() {
    const char* e = std::getenv("FRINGE_USB_EMULATOR_CLOCK");
    if (!e || !*e) return Clock::Realtime;
    try {
        return parse_clock(e);
    } catch (const std::invalid_argument&) {
        throw std::invalid_argument(std::string("FRINGE_USB_EMULATOR_CLOCK='") + e + "' (known: realtime, paced)");
    }
}

UsbEmulatorOptions parse_usb_emulator_options(const std::string& spec) {
    UsbEmulatorOptions o;
    std::size_t pos = 0;
    while (pos < spec.size()) {
        auto comma = spec.find(',', pos);
        if (comma == std::string::npos) comma = spec.size();
        const std::string kv = spec.substr(pos, comma - pos);
        pos = comma + 1;
        if (kv.empty()) continue;
        const auto eq = kv.find('=');
        const std::string k = kv.substr(0, eq), v = eq == std::string::npos ? "" : kv.substr(eq + 1);
        try {
            if (k == "serial") o.serial = v;
            else if (k == "vid") o.vid = static_cast<std::uint16_t>(std::stoul(v, nullptr, 16));
            else if (k == "pid") o.pid = static_cast<std::uint16_t>(std::stoul(v, nullptr, 16));
            else if (k == "adc_bits") o.adc_bits = std::stoi(v);
            else if (k == "noise_v") o.noise_v = std::stod(v);
            else if (k == "stall_after") o.stall_after = std::stoll(v);
            else if (k == "silent_after") o.silent_after = std::stoll(v);
            else if (k == "drop_at") o.drop_at = std::stoll(v);
            else if (k == "drop_count") o.drop_count = std::stoll(v);
            else if (k == "unplug_after") o.unplug_after = std::stoll(v);
            else if (k == "seed") o.seed = std::stoull(v);
            else if (k == "time_scale") o.time_scale = std::stod(v);
            else if (k == "clock") o.clock = parse_clock(v);
            else throw std::invalid_argument("unknown key");
        } catch (const std::exception&) {
            throw std::invalid_argument("usb emulator option '" + kv +
                                        "' (known: serial, vid, pid, adc_bits, noise_v, stall_after, silent_after, drop_at, drop_count, unplug_after, seed, time_scale, clock=realtime|paced)");
        }
    }
    return o;
}

struct UsbEmulator::Impl {
    UsbEmulatorOptions o;
    UMockdevTestbed* tb = nullptr;
    UMockdevIoctlBase* handler = nullptr;
    mutable std::mutex mu;
    std::mt19937_64 rng;
    std::normal_distribution<double> gauss{0.0, 1.0};
    // stream state
    bool running = false, unplugged = false, stalled = false;
    bool clock_started = false;  // the sample clock starts with the first OUT frame after START
    bool out_ended = false;      // a short OUT frame ended the output: convert the rest, then stop
    std::uint32_t rate_hz = 100000;
    std::uint16_t frame_samples = 512;
    clk::time_point t0;
    std::uint64_t produced = 0;  // IN frames produced since START
    usbp::Status st{};
    std::deque<std::int16_t> fifo_s, fifo_c;  // DAC samples not yet converted
    std::deque<Urb> in_pending, out_pending, done;

    explicit Impl(UsbEmulatorOptions opt) : o(std::move(opt)), rng(o.seed) {}

    std::size_t fifo_cap() const { return static_cast<std::size_t>(frame_samples) * 16; }

    std::int16_t adc(std::int16_t code) {
        double v = code;
        if (o.noise_v > 0) v += o.noise_v / o.range_v * 32768.0 * gauss(rng);
        if (o.adc_bits > 0 && o.adc_bits < 16) {
            const double q = std::ldexp(1.0, 16 - o.adc_bits);
            v = std::floor(v / q + 0.5) * q;
        }
        return static_cast<std::int16_t>(std::clamp(std::nearbyint(v), -32768.0, 32767.0));
    }

    void finish(Urb& r, int status, int actual) {
        r.u()->status = status;
        r.u()->actual_length = actual;
        done.push_back(r);
    }

    void fail_all(int status) {
        for (auto* q : {&in_pending, &out_pending})
            while (!q->empty()) {
                finish(q->front(), status, 0);
                q->pop_front();
            }
    }

    // OUT frames the FIFO has room for complete (USB flow control: the rest wait, NAKed).
    void accept_out() {
        while (!out_pending.empty()) {
            Urb& r = out_pending.front();
            usbp::FrameHeader h{};
            const int len = r.u()->buffer_length;
            if (len >= static_cast<int>(sizeof h)) std::memcpy(&h, r.buf->data, sizeof h);
            if (len < static_cast<int>(sizeof h) || h.magic != usbp::kMagic || len < static_cast<int>(usbp::frame_bytes(h.samples, false))) {
                finish(r, -EPROTO, 0);  // a malformed frame: the host sees a transfer error
                out_pending.pop_front();
                continue;
            }
            if (fifo_s.size() + h.samples > fifo_cap()) break;
            if (h.samples < frame_samples) out_ended = true;
            const auto* p = r.buf->data + sizeof h;
            for (std::size_t i = 0; i < h.samples; ++i) {
                std::int16_t a, b;
                usbp::get_pair(p, i, a, b);
                fifo_s.push_back(a);
                fifo_c.push_back(b);
            }
            finish(r, 0, len);
            out_pending.pop_front();
            if (running && !clock_started) {
                clock_started = true;
                t0 = clk::now();
            }
        }
    }

    bool dropped_on_board(std::uint64_t seq) const {
        return o.drop_at >= 0 && static_cast<long long>(seq) >= o.drop_at && static_cast<long long>(seq) < o.drop_at + o.drop_count;
    }

    // The sample clock. Real time: the IN frames due since the clock started are produced now.
    // Paced: a frame is produced once its samples are in the FIFO (or the output has ended) and
    // the host has an IN transfer waiting for it.
    void advance() {
        if (!running || unplugged) return;
        accept_out();
        if (!clock_started) return;
        const bool paced = o.clock == UsbEmulatorOptions::Clock::Paced;
        std::uint64_t due = 0;
        if (!paced) {
            const double elapsed = o.time_scale * std::chrono::duration<double>(clk::now() - t0).count();
            due = static_cast<std::uint64_t>(elapsed * rate_hz / frame_samples);
        }
        while (paced || produced < due) {
            if (o.silent_after >= 0 && static_cast<long long>(produced) >= o.silent_after) return;
            if (o.unplug_after >= 0 && static_cast<long long>(produced) >= o.unplug_after) {
                unplug_locked();
                return;
            }
            if (out_ended && fifo_s.empty()) return;  // the stream is over
            if (paced) {
                if (!out_ended && fifo_s.size() < frame_samples) return;          // waits for the host's samples
                if (in_pending.empty() && !dropped_on_board(produced)) return;   // waits for the host to ask
            }
            if (o.stall_after >= 0 && static_cast<long long>(produced) >= o.stall_after) stalled = true;
            // After the output ended, the last frame holds what is left.
            const std::size_t nf = out_ended ? std::min<std::size_t>(frame_samples, fifo_s.size()) : frame_samples;
            const std::uint32_t seq = static_cast<std::uint32_t>(produced++);
            ++st.in_frames;
            bool under = false;
            std::vector<std::int16_t> s(nf), c(nf);
            for (std::size_t i = 0; i < nf; ++i) {
                if (fifo_s.empty()) {
                    under = true;  // nothing to convert: the DAC holds zero
                    s[i] = c[i] = 0;
                    continue;
                }
                s[i] = fifo_s.front();
                c[i] = fifo_c.front();
                fifo_s.pop_front();
                fifo_c.pop_front();
            }
            if (under) ++st.underflows;
            accept_out();
            const bool lost = dropped_on_board(seq);
            if (lost || in_pending.empty()) {  // never sent, or the host had no transfer waiting: gone
                ++st.in_dropped;
                continue;
            }
            Urb r = in_pending.front();
            in_pending.pop_front();
            if (stalled) {
                finish(r, -EPIPE, 0);
                continue;
            }
            const std::size_t bytes = usbp::frame_bytes(nf, false);
            if (static_cast<std::size_t>(r.u()->buffer_length) < bytes) {
                finish(r, -EOVERFLOW, 0);
                continue;
            }
            usbp::FrameHeader h{usbp::kMagic, seq, static_cast<std::uint16_t>(nf), static_cast<std::uint16_t>(under ? usbp::kFlagUnderflow : 0), 0};
            std::memcpy(r.buf->data, &h, sizeof h);
            auto* p = r.buf->data + sizeof h;
            for (std::size_t i = 0; i < nf; ++i) usbp::put_pair(p, i, adc(s[i]), adc(c[i]));
            finish(r, 0, static_cast<int>(bytes));
        }
    }

    void unplug_locked() {
        unplugged = true;
        running = false;
        fail_all(-ENODEV);
    }

    // Vendor control requests; returns the data length or -errno (EPIPE: stall).
    int control(const std::uint8_t* setup, std::uint8_t* data) {
        const std::uint8_t type = setup[0], req = setup[1];
        std::uint16_t wlen;
        std::memcpy(&wlen, setup + 6, 2);
        if ((type & 0x60) != 0x40) return -EPIPE;  // not vendor
        switch (req) {
            case usbp::GetInfo: {
                usbp::Info i{};
                i.protocol = usbp::kProtocolVersion;
                i.flags = 0;
                i.adc_bits = static_cast<std::uint8_t>(o.adc_bits);
                i.dac_bits = 16;
                i.range_mv = static_cast<std::uint16_t>(std::lround(o.range_v * 1000));
                i.max_rate_hz = o.max_rate_hz;
                i.max_frame_samples = 16384;
                std::snprintf(i.name, sizeof i.name, "fringe-usb-sim");
                std::memcpy(i.serial, o.serial.data(), std::min(o.serial.size(), sizeof i.serial));  // not NUL-terminated when 16 long
                const int n = std::min<int>(wlen, sizeof i);
                std::memcpy(data, &i, static_cast<std::size_t>(n));
                return n;
            }
            case usbp::SetRate: {
                if (wlen < sizeof(usbp::RateRequest)) return -EPIPE;
                usbp::RateRequest r;
                std::memcpy(&r, data, sizeof r);
                if (r.rate_hz == 0 || r.rate_hz > o.max_rate_hz || r.frame_samples == 0 || r.frame_samples > 16384) return -EPIPE;
                rate_hz = r.rate_hz;
                frame_samples = r.frame_samples;
                return 0;
            }
            case usbp::Start:
                running = true;
                clock_started = false;
                out_ended = false;
                stalled = false;
                produced = 0;
                st = usbp::Status{};
                st.running = 1;
                fifo_s.clear();
                fifo_c.clear();
                t0 = clk::now();
                return 0;
            case usbp::Stop:
                running = false;
                st.running = 0;
                return 0;
            case usbp::GetStatus: {
                const int n = std::min<int>(wlen, sizeof st);
                std::memcpy(data, &st, static_cast<std::size_t>(n));
                return n;
            }
            default: return -EPIPE;
        }
    }

    gboolean on_ioctl(UMockdevIoctlClient* client) {
        std::lock_guard<std::mutex> l(mu);
        const gulong request = umockdev_ioctl_client_get_request(client);
        UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
        switch (request) {
            case USBDEVFS_GET_CAPABILITIES: {
                UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(guint32), nullptr);
                // Scatter-gather: libusb sends each transfer as one URB, so one URB is one frame.
                const guint32 caps = USBDEVFS_CAP_BULK_SCATTER_GATHER | USBDEVFS_CAP_NO_PACKET_SIZE_LIM | USBDEVFS_CAP_REAP_AFTER_DISCONNECT | USBDEVFS_CAP_ZERO_PACKET;
                std::memcpy(d->data, &caps, sizeof caps);
                g_object_unref(d);
                umockdev_ioctl_client_complete(client, 0, 0);
                return TRUE;
            }
            case USBDEVFS_CLAIMINTERFACE:
            case USBDEVFS_RELEASEINTERFACE:
            case USBDEVFS_CLEAR_HALT:
            case USBDEVFS_RESET:
            case USBDEVFS_RESETEP:
                if (unplugged) umockdev_ioctl_client_complete(client, -1, ENODEV);
                else {
                    if (request == USBDEVFS_CLEAR_HALT) stalled = false;
                    umockdev_ioctl_client_complete(client, 0, 0);
                }
                return TRUE;
            case USBDEVFS_SUBMITURB: {
                if (unplugged) {
                    umockdev_ioctl_client_complete(client, -1, ENODEV);
                    return TRUE;
                }
                Urb r;
                r.urb = umockdev_ioctl_data_resolve(arg, 0, sizeof(usbdevfs_urb), nullptr);
                r.buf = umockdev_ioctl_data_resolve(r.urb, offsetof(usbdevfs_urb, buffer), static_cast<gsize>(r.u()->buffer_length), nullptr);
                const auto* u = r.u();
                if (u->type == USBDEVFS_URB_TYPE_CONTROL) {
                    const int n = u->buffer_length >= 8 ? control(r.buf->data, r.buf->data + 8) : -EPIPE;
                    finish(r, n < 0 ? n : 0, n < 0 ? 0 : n);  // control actual_length excludes the setup packet
                } else if (u->type == USBDEVFS_URB_TYPE_BULK && u->endpoint == usbp::kEpIn) {
                    in_pending.push_back(r);
                } else if (u->type == USBDEVFS_URB_TYPE_BULK && u->endpoint == usbp::kEpOut) {
                    out_pending.push_back(r);
                } else {
                    r.release();
                    umockdev_ioctl_client_complete(client, -1, EINVAL);
                    return TRUE;
                }
                umockdev_ioctl_client_complete(client, 0, 0);
                advance();
                return TRUE;
            }
            case USBDEVFS_REAPURB:
            case USBDEVFS_REAPURBNDELAY: {
                advance();
                if (done.empty()) {
                    umockdev_ioctl_client_complete(client, -1, unplugged ? ENODEV : EAGAIN);
                    return TRUE;
                }
                Urb r = done.front();
                done.pop_front();
                UMockdevIoctlData* ptr = umockdev_ioctl_data_resolve(arg, 0, sizeof(gpointer), nullptr);
                umockdev_ioctl_data_set_ptr(ptr, 0, r.urb);
                umockdev_ioctl_client_complete(client, 0, 0);
                g_object_unref(ptr);
                r.release();
                return TRUE;
            }
            case USBDEVFS_DISCARDURB: {
                gulong addr = 0;
                std::memcpy(&addr, arg->data, sizeof addr);
                for (auto* q : {&in_pending, &out_pending})
                    for (auto it = q->begin(); it != q->end(); ++it)
                        if (it->urb->client_addr == addr) {
                            finish(*it, -ENOENT, 0);
                            q->erase(it);
                            umockdev_ioctl_client_complete(client, 0, 0);
                            return TRUE;
                        }
                umockdev_ioctl_client_complete(client, -1, EINVAL);
                return TRUE;
            }
            default: return FALSE;
        }
    }

    static gboolean on_ioctl_cb(UMockdevIoctlBase*, UMockdevIoctlClient* client, gpointer self) {
        return static_cast<Impl*>(self)->on_ioctl(client);
    }
};

UsbEmulator::UsbEmulator(UsbEmulatorOptions o) : impl_(std::make_unique<Impl>(std::move(o))) {
    auto& im = *impl_;
    im.tb = umockdev_testbed_new();
    if (!umockdev_in_mock_environment()) {
        g_object_unref(im.tb);
        throw std::runtime_error("the USB emulator needs umockdev's preload: run with LD_PRELOAD=libumockdev-preload.so.0");
    }
    im.handler = umockdev_ioctl_base_new();
    g_signal_connect(im.handler, "handle-ioctl", G_CALLBACK(&Impl::on_ioctl_cb), &im);
    GError* err = nullptr;
    if (!umockdev_testbed_attach_ioctl(im.tb, "/dev/bus/usb/001/001", im.handler, &err)) {
        const std::string msg = err ? err->message : "?";
        g_clear_error(&err);
        throw std::runtime_error("umockdev attach: " + msg);
    }
    // Device, configuration, one vendor interface, bulk OUT 0x01 and IN 0x81 (512 bytes).
    const std::vector<std::uint8_t> desc = {
        18, 1, 0x00, 0x02, 0xff, 0, 0, 64, static_cast<std::uint8_t>(im.o.vid & 0xff), static_cast<std::uint8_t>(im.o.vid >> 8),
        static_cast<std::uint8_t>(im.o.pid & 0xff), static_cast<std::uint8_t>(im.o.pid >> 8), 0x00, 0x01, 1, 2, 3, 1,
        9, 2, 32, 0, 1, 1, 0, 0x80, 50,
        9, 4, 0, 0, 2, 0xff, 0, 0, 0,
        7, 5, usbp::kEpOut, 2, 0x00, 0x02, 0,
        7, 5, usbp::kEpIn, 2, 0x00, 0x02, 0};
    const std::string dev =
        "P: /devices/fringe-usb1\nN: bus/usb/001/001\nE: SUBSYSTEM=usb\nE: DRIVER=usb\nE: BUSNUM=001\nE: DEVNUM=001\n"
        "E: DEVNAME=/dev/bus/usb/001/001\nE: DEVTYPE=usb_device\nA: busnum=1\\n\nA: devnum=1\\n\nA: speed=480\\n\n"
        "A: bConfigurationValue=1\\n\nH: descriptors=" + hex(desc) + "\n";
    if (!umockdev_testbed_add_from_string(im.tb, dev.c_str(), &err)) {
        const std::string msg = err ? err->message : "?";
        g_clear_error(&err);
        throw std::runtime_error("umockdev add device: " + msg);
    }
}

UsbEmulator::~UsbEmulator() {
    auto& im = *impl_;
    {
        std::lock_guard<std::mutex> l(im.mu);
        for (auto* q : {&im.in_pending, &im.out_pending, &im.done})
            for (auto& r : *q) r.release();
    }
    if (im.handler) g_object_unref(im.handler);
    if (im.tb) g_object_unref(im.tb);
}

void UsbEmulator::unplug() {
    std::lock_guard<std::mutex> l(impl_->mu);
    impl_->unplug_locked();
}

usbp::Status UsbEmulator::status() const {
    std::lock_guard<std::mutex> l(impl_->mu);
    return impl_->st;
}

}  // namespace fringe::dev
