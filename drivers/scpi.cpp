#include "scpi.hpp"

#include "device.hpp"
#include "signal_gen/base/text.hpp"

#include <libusb.h>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <stdexcept>

namespace fringe::dev::scpi {

namespace {
using Clock = std::chrono::steady_clock;

Clock::time_point deadline_after(double s) { return Clock::now() + std::chrono::microseconds(static_cast<long long>(std::max(0.0, s) * 1e6)); }
int ms_left(Clock::time_point dl) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(dl - Clock::now()).count();
    return static_cast<int>(std::clamp<long long>(left, 0, 1 << 30));
}
std::string fmt_s(double s) {
    char b[32];
    std::snprintf(b, sizeof b, "%g", s);
    return b;
}
// A command as errors quote it: binary uploads cut short.
std::string cmd_quote(std::string_view cmd) {
    std::string s;
    for (char c : cmd.substr(0, 60)) s += (c >= 32 && c < 127) ? c : '.';
    if (cmd.size() > 60) s += "...(" + std::to_string(cmd.size()) + " bytes)";
    return "'" + s + "'";
}
}  // namespace

// ---- blocks ----

std::string encode_block(std::string_view data) {
    const std::string len = std::to_string(data.size());
    std::string out;
    out.reserve(2 + len.size() + data.size());
    out += '#';
    out += static_cast<char>('0' + len.size());
    out += len;
    out.append(data);
    return out;
}

BlockHeader parse_block_header(std::string_view buf, std::size_t max_bytes) {
    BlockHeader h;
    std::size_t i = 0;
    while (i < buf.size() && (buf[i] == ' ' || buf[i] == '\t')) ++i;
    if (i >= buf.size()) return h;
    if (buf[i] != '#') {
        h.status = BlockHeader::Status::Bad;
        h.error = "a binary block starts with '#', got byte " + std::to_string(static_cast<unsigned char>(buf[i]));
        return h;
    }
    if (i + 1 >= buf.size()) return h;
    const char nd = buf[i + 1];
    if (nd < '0' || nd > '9') {
        h.status = BlockHeader::Status::Bad;
        h.error = "the block's digit count is not a digit";
        return h;
    }
    if (nd == '0') {
        h.status = BlockHeader::Status::Ok;
        h.indefinite = true;
        h.header_bytes = i + 2;
        return h;
    }
    const std::size_t n = static_cast<std::size_t>(nd - '0');
    if (buf.size() < i + 2 + n) return h;
    std::size_t len = 0;
    for (std::size_t k = 0; k < n; ++k) {
        const char c = buf[i + 2 + k];
        if (c < '0' || c > '9') {
            h.status = BlockHeader::Status::Bad;
            h.error = "the block's length has a non-digit";
            return h;
        }
        len = len * 10 + static_cast<std::size_t>(c - '0');  // at most 9 digits: no overflow
    }
    if (len > max_bytes) {
        h.status = BlockHeader::Status::Bad;
        h.error = "the block declares " + std::to_string(len) + " bytes, more than the " + std::to_string(max_bytes) + " allowed";
        return h;
    }
    h.status = BlockHeader::Status::Ok;
    h.header_bytes = i + 2 + n;
    h.data_bytes = len;
    return h;
}

std::string decode_block(std::string_view r, std::size_t max_bytes) {
    const BlockHeader h = parse_block_header(r, max_bytes);
    if (h.status == BlockHeader::Status::Bad) throw std::runtime_error(h.error);
    if (h.status == BlockHeader::Status::NeedMore) throw std::runtime_error("truncated block header");
    std::string_view rest = r.substr(h.header_bytes);
    if (h.indefinite) {
        if (!rest.empty() && rest.back() == '\n') rest.remove_suffix(1);
        if (rest.size() > max_bytes) throw std::runtime_error("indefinite block longer than the " + std::to_string(max_bytes) + " bytes allowed");
        return std::string(rest);
    }
    if (rest.size() < h.data_bytes)
        throw std::runtime_error("truncated block: " + std::to_string(rest.size()) + " of " + std::to_string(h.data_bytes) + " declared bytes");
    std::string_view tail = rest.substr(h.data_bytes);
    if (!tail.empty() && tail[0] == '\r') tail.remove_prefix(1);
    if (!tail.empty() && tail[0] == '\n') tail.remove_prefix(1);
    if (!tail.empty()) throw std::runtime_error(std::to_string(tail.size()) + " unexpected bytes after the block");
    return std::string(rest.substr(0, h.data_bytes));
}

ErrorEntry parse_error_entry(std::string_view r) {
    while (!r.empty() && (r.back() == '\n' || r.back() == '\r' || r.back() == ' ')) r.remove_suffix(1);
    const auto comma = r.find(',');
    const std::string num(r.substr(0, comma));
    ErrorEntry e;
    char* end = nullptr;
    const long v = std::strtol(num.c_str(), &end, 10);
    if (num.empty() || end == num.c_str() || *end != '\0' || v < -100000 || v > 100000)
        throw std::runtime_error("not an error queue entry: " + cmd_quote(r));
    e.code = static_cast<int>(v);
    if (comma != std::string_view::npos) {
        std::string_view t = r.substr(comma + 1);
        if (t.size() >= 2 && t.front() == '"' && t.back() == '"') t = t.substr(1, t.size() - 2);
        e.text = std::string(t);
    }
    return e;
}

// ---- USBTMC ----
namespace usbtmc {

std::uint8_t next_tag(std::uint8_t tag) { return tag >= 255 ? 1 : static_cast<std::uint8_t>(tag + 1); }

namespace {
void put_header(std::uint8_t* h, std::uint8_t msg, std::uint8_t tag, std::uint32_t size) {
    h[0] = msg;
    h[1] = tag;
    h[2] = static_cast<std::uint8_t>(~tag);
    h[3] = 0;
    for (int k = 0; k < 4; ++k) h[4 + k] = static_cast<std::uint8_t>(size >> (8 * k));  // little-endian
}
}  // namespace

std::vector<std::uint8_t> encode_out(std::uint8_t tag, std::string_view data, bool eom) {
    if (tag == 0) throw std::invalid_argument("USBTMC bTag must be 1..255");
    if (data.empty() || data.size() > 0xFFFFFFFFu) throw std::invalid_argument("USBTMC TransferSize must be 1..2^32-1");
    const std::size_t padded = (data.size() + 3) / 4 * 4;
    std::vector<std::uint8_t> out(kHeaderBytes + padded, 0);
    put_header(out.data(), kDevDepMsgOut, tag, static_cast<std::uint32_t>(data.size()));
    out[8] = eom ? 1 : 0;  // bmTransferAttributes D0: EOM
    std::memcpy(out.data() + kHeaderBytes, data.data(), data.size());
    return out;
}

std::array<std::uint8_t, kHeaderBytes> encode_request_in(std::uint8_t tag, std::uint32_t max_bytes, std::optional<char> term_char) {
    if (tag == 0) throw std::invalid_argument("USBTMC bTag must be 1..255");
    std::array<std::uint8_t, kHeaderBytes> h{};
    put_header(h.data(), kRequestDevDepMsgIn, tag, max_bytes);
    if (term_char) {
        h[8] = 2;  // D1: TermCharEnabled
        h[9] = static_cast<std::uint8_t>(*term_char);
    }
    return h;
}

InHeader decode_in_header(const std::uint8_t* p, std::size_t n, std::uint8_t expected_tag, std::uint32_t asked) {
    if (n < kHeaderBytes) throw std::runtime_error("USBTMC Bulk-IN transfer of " + std::to_string(n) + " bytes is shorter than its 12-byte header");
    if (p[0] != kDevDepMsgIn) throw std::runtime_error("USBTMC Bulk-IN MsgID " + std::to_string(p[0]) + " (expected DEV_DEP_MSG_IN, 2)");
    if (p[1] != expected_tag || p[2] != static_cast<std::uint8_t>(~expected_tag))
        throw std::runtime_error("USBTMC Bulk-IN bTag " + std::to_string(p[1]) + "/" + std::to_string(p[2]) + " does not answer request " + std::to_string(expected_tag));
    if (p[3] != 0 || p[9] != 0 || p[10] != 0 || p[11] != 0) throw std::runtime_error("USBTMC Bulk-IN header has non-zero reserved bytes");
    if (p[8] & ~0x3u) throw std::runtime_error("USBTMC Bulk-IN bmTransferAttributes has reserved bits set");
    InHeader h;
    h.tag = p[1];
    for (int k = 0; k < 4; ++k) h.transfer_size |= static_cast<std::uint32_t>(p[4 + k]) << (8 * k);
    h.eom = (p[8] & 1) != 0;
    if (h.transfer_size > asked)
        throw std::runtime_error("USBTMC Bulk-IN TransferSize " + std::to_string(h.transfer_size) + " exceeds the " + std::to_string(asked) + " bytes requested");
    return h;
}

}  // namespace usbtmc

// ---- TCP ----
namespace {

class TcpLink final : public Link {
public:
    TcpLink(const std::string& host, int port, double timeout_s) : where_(host + ":" + std::to_string(port)) {
        addrinfo hints{};
        hints.ai_family = AF_UNSPEC;
        hints.ai_socktype = SOCK_STREAM;
        addrinfo* res = nullptr;
        const int g = getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &res);
        if (g != 0) throw std::runtime_error(where_ + ": " + gai_strerror(g));
        std::string last = "no address";
        const auto dl = deadline_after(timeout_s);
        for (addrinfo* a = res; a; a = a->ai_next) {
            const int fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, a->ai_protocol);
            if (fd < 0) continue;
            int rc = ::connect(fd, a->ai_addr, a->ai_addrlen);
            if (rc != 0 && errno == EINPROGRESS) {
                pollfd pf{fd, POLLOUT, 0};
                rc = ::poll(&pf, 1, ms_left(dl));
                if (rc == 0) {
                    last = "connect timed out after " + fmt_s(timeout_s) + " s";
                    ::close(fd);
                    continue;
                }
                int err = 0;
                socklen_t len = sizeof err;
                getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len);
                rc = err ? -1 : 0;
                errno = err;
            }
            if (rc != 0) {
                last = std::string("connect: ") + std::strerror(errno);
                ::close(fd);
                continue;
            }
            int one = 1;
            setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
            fd_ = fd;
            break;
        }
        freeaddrinfo(res);
        if (fd_ < 0) throw std::runtime_error(where_ + ": " + last);
    }
    ~TcpLink() override {
        if (fd_ >= 0) ::close(fd_);
    }
    void write_message(std::string_view bytes, double timeout_s) override {
        std::string msg(bytes);
        if (msg.empty() || msg.back() != '\n') msg += '\n';
        const auto dl = deadline_after(timeout_s);
        std::size_t off = 0;
        while (off < msg.size()) {
            const ssize_t n = ::send(fd_, msg.data() + off, msg.size() - off, MSG_NOSIGNAL);
            if (n > 0) {
                off += static_cast<std::size_t>(n);
                continue;
            }
            if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
                pollfd pf{fd_, POLLOUT, 0};
                if (::poll(&pf, 1, ms_left(dl)) == 0) throw TimeoutError("send timed out after " + fmt_s(timeout_s) + " s (the instrument reads nothing)");
                continue;
            }
            if (n < 0 && errno == EINTR) continue;
            throw std::runtime_error(std::string("send: ") + std::strerror(errno) + " (connection lost)");
        }
    }
    std::size_t read_some(char* buf, std::size_t n, double timeout_s, bool* end) override {
        *end = false;
        const auto dl = deadline_after(timeout_s);
        for (;;) {
            const ssize_t r = ::recv(fd_, buf, n, 0);
            if (r > 0) return static_cast<std::size_t>(r);
            if (r == 0) throw std::runtime_error("connection closed by the instrument");
            if (errno == EINTR) continue;
            if (errno != EAGAIN && errno != EWOULDBLOCK) throw std::runtime_error(std::string("recv: ") + std::strerror(errno) + " (connection lost)");
            pollfd pf{fd_, POLLIN, 0};
            const int p = ::poll(&pf, 1, ms_left(dl));
            if (p == 0) throw TimeoutError("no reply within " + fmt_s(timeout_s) + " s");
        }
    }
    std::string describe() const override { return where_; }
    bool message_framed() const override { return false; }

private:
    std::string where_;
    int fd_ = -1;
};

// ---- USBTMC over libusb ----
class UsbtmcLink final : public Link {
public:
    UsbtmcLink(std::uint16_t vid, std::uint16_t pid, const std::string& serial, double timeout_s) {
        char w[64];
        std::snprintf(w, sizeof w, "USBTMC %04x:%04x", vid, pid);
        where_ = w;
        (void)timeout_s;
        if (int rc = libusb_init(&ctx_); rc != 0) throw std::runtime_error(where_ + ": libusb_init: " + libusb_error_name(rc));
        libusb_device** list = nullptr;
        const ssize_t n = libusb_get_device_list(ctx_, &list);
        std::string why = "no such device";
        for (ssize_t i = 0; i < n && !h_; ++i) {
            libusb_device_descriptor dd{};
            if (libusb_get_device_descriptor(list[i], &dd) != 0 || dd.idVendor != vid || dd.idProduct != pid) continue;
            libusb_device_handle* h = nullptr;
            if (int rc = libusb_open(list[i], &h); rc != 0) {
                why = std::string("open: ") + libusb_error_name(rc);
                continue;
            }
            if (!serial.empty()) {
                unsigned char s[256] = {};
                if (dd.iSerialNumber == 0 || libusb_get_string_descriptor_ascii(h, dd.iSerialNumber, s, sizeof s) <= 0 ||
                    serial != reinterpret_cast<char*>(s)) {
                    why = "no device with serial " + serial;
                    libusb_close(h);
                    continue;
                }
            }
            if (!find_interface(list[i])) {
                why = "the device has no USBTMC interface (class 0xFE, subclass 3) with bulk endpoints";
                libusb_close(h);
                continue;
            }
            libusb_set_auto_detach_kernel_driver(h, 1);  // the kernel's usbtmc driver, if bound
            if (int rc = libusb_claim_interface(h, iface_); rc != 0) {
                why = std::string("claim interface: ") + libusb_error_name(rc);
                libusb_close(h);
                continue;
            }
            h_ = h;
        }
        if (list) libusb_free_device_list(list, 1);
        if (!h_) {
            libusb_exit(ctx_);
            throw std::runtime_error(where_ + ": " + why);
        }
    }
    ~UsbtmcLink() override {
        libusb_release_interface(h_, iface_);
        libusb_close(h_);
        libusb_exit(ctx_);
    }
    void write_message(std::string_view bytes, double timeout_s) override {
        constexpr std::size_t kChunk = 1 << 20;
        for (std::size_t off = 0; off < bytes.size() || off == 0;) {
            const std::size_t n = std::min(kChunk, bytes.size() - off);
            tag_ = usbtmc::next_tag(tag_);
            auto pkt = usbtmc::encode_out(tag_, bytes.substr(off, n), off + n == bytes.size());
            bulk(ep_out_, pkt.data(), pkt.size(), timeout_s, true);
            off += n;
            if (n == 0) break;
        }
    }
    std::size_t read_some(char* buf, std::size_t n, double timeout_s, bool* end) override {
        *end = false;
        if (left_ == 0) {  // a new transfer: ask for at most n bytes
            const auto asked = static_cast<std::uint32_t>(std::min<std::size_t>(n, 1 << 20));
            tag_ = usbtmc::next_tag(tag_);
            auto req = usbtmc::encode_request_in(tag_, asked);
            bulk(ep_out_, req.data(), req.size(), timeout_s, true);
            in_.assign(usbtmc::kHeaderBytes + asked + 3 + max_packet_, 0);
            const std::size_t got = bulk(ep_in_, in_.data(), in_.size(), timeout_s, false);
            const auto h = usbtmc::decode_in_header(in_.data(), got, tag_, asked);
            eom_ = h.eom;
            left_ = h.transfer_size;
            have_ = got - usbtmc::kHeaderBytes;
            off_ = usbtmc::kHeaderBytes;
            while (have_ < left_) {  // the transfer continues in further packets
                const std::size_t more = bulk(ep_in_, in_.data() + off_ + have_, in_.size() - off_ - have_, timeout_s, false);
                if (more == 0) break;
                have_ += more;
            }
            if (have_ < left_) throw std::runtime_error("USBTMC transfer ended after " + std::to_string(have_) + " of " + std::to_string(left_) + " bytes");
        }
        const std::size_t k = std::min(n, left_);
        std::memcpy(buf, in_.data() + off_, k);
        off_ += k;
        left_ -= k;
        *end = left_ == 0 && eom_;
        return k;
    }
    std::string describe() const override { return where_; }
    bool message_framed() const override { return true; }

private:
    bool find_interface(libusb_device* d) {
        libusb_config_descriptor* cfg = nullptr;
        if (libusb_get_active_config_descriptor(d, &cfg) != 0) return false;
        bool ok = false;
        for (int i = 0; i < cfg->bNumInterfaces && !ok; ++i)
            for (int a = 0; a < cfg->interface[i].num_altsetting && !ok; ++a) {
                const auto& id = cfg->interface[i].altsetting[a];
                if (id.bInterfaceClass != 0xFE || id.bInterfaceSubClass != 3) continue;
                ep_in_ = ep_out_ = 0;
                for (int e = 0; e < id.bNumEndpoints; ++e) {
                    const auto& ep = id.endpoint[e];
                    if ((ep.bmAttributes & 3) != LIBUSB_TRANSFER_TYPE_BULK) continue;
                    if (ep.bEndpointAddress & 0x80) {
                        ep_in_ = ep.bEndpointAddress;
                        max_packet_ = ep.wMaxPacketSize;
                    } else {
                        ep_out_ = ep.bEndpointAddress;
                    }
                }
                if (ep_in_ && ep_out_) {
                    iface_ = id.bInterfaceNumber;
                    ok = true;
                }
            }
        libusb_free_config_descriptor(cfg);
        return ok;
    }
    std::size_t bulk(unsigned char ep, std::uint8_t* data, std::size_t n, double timeout_s, bool whole) {
        int done = 0;
        const int rc = libusb_bulk_transfer(h_, ep, data, static_cast<int>(n), &done, static_cast<unsigned>(std::max(1.0, timeout_s * 1000)));
        if (rc == LIBUSB_ERROR_TIMEOUT) {
            libusb_clear_halt(h_, ep);  // USBTMC 4.2.1.4 asks for INITIATE_ABORT_BULK_IN/OUT; a clear is the minimum
            throw TimeoutError("no USBTMC transfer within " + fmt_s(timeout_s) + " s");
        }
        if (rc != 0) throw std::runtime_error(std::string("USBTMC bulk transfer: ") + libusb_error_name(rc) + (rc == LIBUSB_ERROR_NO_DEVICE ? " (instrument unplugged)" : ""));
        if (whole && static_cast<std::size_t>(done) != n) throw std::runtime_error("USBTMC bulk-OUT sent " + std::to_string(done) + " of " + std::to_string(n) + " bytes");
        return static_cast<std::size_t>(done);
    }

    std::string where_;
    libusb_context* ctx_ = nullptr;
    libusb_device_handle* h_ = nullptr;
    int iface_ = 0, max_packet_ = 512;
    unsigned char ep_in_ = 0, ep_out_ = 0;
    std::uint8_t tag_ = 0;
    std::vector<std::uint8_t> in_;
    std::size_t left_ = 0, have_ = 0, off_ = 0;
    bool eom_ = false;
};

}  // namespace

std::unique_ptr<Link> connect_tcp(const std::string& host, int port, double timeout_s) { return std::make_unique<TcpLink>(host, port, timeout_s); }
std::unique_ptr<Link> open_usbtmc(std::uint16_t vid, std::uint16_t pid, const std::string& serial, double timeout_s) {
    return std::make_unique<UsbtmcLink>(vid, pid, serial, timeout_s);
}

// ---- Session ----

Session::Session(std::unique_ptr<Link> link, std::string device_uri, double timeout_s, std::size_t max_block_bytes)
    : link_(std::move(link)), uri_(std::move(device_uri)), timeout_s_(timeout_s), max_block_(max_block_bytes) {}

void Session::fail(std::string_view what, const std::exception& e) {
    if (dynamic_cast<const TimeoutError*>(&e))
        throw InstrumentTimeout(uri_, link_->describe() + ": timeout waiting for " + std::string(what) + ": " + e.what() + " (instrument silent or busy)");
    throw DeviceError(uri_, link_->describe() + ": " + std::string(what) + ": " + e.what());
}

void Session::check_usable() const {
    if (!broken_.empty()) throw DeviceError(uri_, link_->describe() + ": the session is out of step (" + broken_ + "): reopen the instrument");
}

void Session::send(std::string_view command) {
    check_usable();
    try {
        link_->write_message(command, timeout_s_);
    } catch (const std::exception& e) {
        fail("sending " + cmd_quote(command), e);
    }
}

bool Session::fill(std::string_view waited_for, std::size_t max_n, Clock::time_point dl) {
    if (pos_ > 0 && pos_ * 2 > buf_.size()) {
        buf_.erase(0, pos_);
        pos_ = 0;
    }
    char tmp[65536];
    bool end = false;
    const double left_s = std::chrono::duration<double>(dl - Clock::now()).count();
    if (left_s <= 0) return false;
    try {
        const std::size_t n = link_->read_some(tmp, std::clamp<std::size_t>(max_n, 1, sizeof tmp), left_s, &end);
        buf_.append(tmp, n);
        at_end_ = end;
    } catch (const TimeoutError&) {
        return false;
    } catch (const std::exception& e) {
        fail("the reply to " + cmd_quote(waited_for), e);
    }
    return true;
}

std::string Session::read_line(std::string_view waited_for, std::size_t max_bytes) {
    check_usable();
    if (max_bytes == 0) max_bytes = max_block_;
    const auto dl = deadline_after(timeout_s_);
    const std::string what = "the reply to " + cmd_quote(waited_for);
    auto too_long = [&] {
        // The rest of the line is not read: the stream can no longer be framed.
        broken_ = "the reply to " + cmd_quote(waited_for) + " was longer than " + std::to_string(max_bytes) + " bytes";
        fail(what, std::runtime_error("reply longer than " + std::to_string(max_bytes) + " bytes; it began " + cmd_quote(std::string_view(buf_).substr(pos_, 60))));
    };
    for (;;) {
        const auto nl = buf_.find('\n', pos_);
        if (nl != std::string::npos) {
            std::string line = buf_.substr(pos_, nl - pos_);
            if (!line.empty() && line.back() == '\r') line.pop_back();
            if (line.size() > max_bytes) too_long();
            pos_ = nl + 1;
            return line;
        }
        const std::size_t pending = buf_.size() - pos_;
        if (link_->message_framed() && at_end_ && pending > 0) {  // EOM without a newline
            if (pending > max_bytes) too_long();
            std::string line = buf_.substr(pos_);
            pos_ = buf_.size();
            return line;
        }
        if (pending > max_bytes + 1) too_long();  // + 1: a "\r" before the "\n"
        // Never more than the cap (and its "\r\n") is buffered for one line.
        if (!fill(waited_for, max_bytes + 2 - pending, dl))
            fail(what, TimeoutError(pending == 0 ? "no reply within " + fmt_s(timeout_s_) + " s"
                                                 : "no complete line within " + fmt_s(timeout_s_) + " s (" + std::to_string(pending) +
                                                       " bytes without a newline)"));
    }
}

std::string Session::read_block(std::string_view waited_for) {
    check_usable();
    const auto dl = deadline_after(timeout_s_);
    const std::string what = "the block answering " + cmd_quote(waited_for);
    BlockHeader h;
    for (;;) {
        while (pos_ < buf_.size() && (buf_[pos_] == '\n' || buf_[pos_] == '\r')) ++pos_;  // a previous block's terminator
        h = parse_block_header(std::string_view(buf_).substr(pos_), max_block_);
        if (h.status == BlockHeader::Status::Bad) {
            // The instrument answered text (an error message, a number): say what it said.
            const auto nl = buf_.find('\n', pos_);
            fail(what, std::runtime_error(h.error + "; the reply began " + cmd_quote(std::string_view(buf_).substr(pos_, nl == std::string::npos ? 60 : nl - pos_))));
        }
        if (h.status == BlockHeader::Status::Ok) break;
        if (!fill(waited_for, 64, dl))
            fail(what, TimeoutError(buf_.size() == pos_ ? "no reply within " + fmt_s(timeout_s_) + " s"
                                                        : "truncated block header (" + std::to_string(buf_.size() - pos_) + " bytes) within " + fmt_s(timeout_s_) + " s"));
    }
    pos_ += h.header_bytes;
    if (h.indefinite) {  // to the end of the message: EOM (USBTMC) or the last newline (TCP)
        for (;;) {
            if (link_->message_framed() ? at_end_ : (!buf_.empty() && buf_.back() == '\n')) break;
            if (buf_.size() - pos_ > max_block_) fail(what, std::runtime_error("an indefinite block longer than " + std::to_string(max_block_) + " bytes"));
            if (!fill(waited_for, max_block_ + 1 - (buf_.size() - pos_), dl))
                fail(what, TimeoutError("indefinite block not ended within " + fmt_s(timeout_s_) + " s (" + std::to_string(buf_.size() - pos_) + " bytes arrived)"));
        }
        std::string data = buf_.substr(pos_);
        if (!data.empty() && data.back() == '\n') data.pop_back();
        pos_ = buf_.size();
        return data;
    }
    if (h.data_bytes > 0) buf_.reserve(pos_ + h.data_bytes);
    while (buf_.size() - pos_ < h.data_bytes) {
        // A block that stops arriving part way is truncated, not unanswered: say how much came.
        // + 2: the "\r\n" that ends the message, usually in the same segment as the data.
        if (!fill(waited_for, h.data_bytes - (buf_.size() - pos_) + 2, dl))
            fail(what, TimeoutError("truncated block: " + std::to_string(buf_.size() - pos_) + " of " + std::to_string(h.data_bytes) +
                                    " declared bytes arrived within " + fmt_s(timeout_s_) + " s"));
    }
    std::string data = buf_.substr(pos_, h.data_bytes);
    pos_ += h.data_bytes;
    if (pos_ < buf_.size() && buf_[pos_] == '\r') ++pos_;
    if (pos_ < buf_.size() && buf_[pos_] == '\n') ++pos_;  // else skipped before the next read
    return data;
}

void Session::check_errors(std::string_view after) {
    if (!error_queue) return;
    std::string errors;
    for (int k = 0; k < 32; ++k) {  // bounded: a queue that never empties is itself an error
        send("SYST:ERR?");
        const std::string r = read_line("SYST:ERR?", kMaxErrorLineBytes);
        ErrorEntry e;
        try {
            e = parse_error_entry(r);
        } catch (const std::exception& ex) {
            throw DeviceError(uri_, link_->describe() + ": after " + cmd_quote(after) + ": SYST:ERR? answered " + cmd_quote(r) + " (" + ex.what() + ")");
        }
        if (e.code == 0) break;
        // The instrument's own words, whole (a NUL no longer ends them) and escaped: they reach
        // reports and terminals.
        errors += (errors.empty() ? "" : "; ") + std::to_string(e.code) + ",\"" + term_escape(e.text) + "\"";
    }
    if (!errors.empty()) throw DeviceError(uri_, "instrument error after " + cmd_quote(after) + ": " + errors);
}

void Session::command(std::string_view cmd) {
    send(cmd);
    check_errors(cmd);
}

std::string Session::query(std::string_view q, std::size_t max_bytes) {
    send(q);
    std::string r = read_line(q, max_bytes);
    check_errors(q);
    return r;
}

std::string Session::query_block(std::string_view q) {
    send(q);
    std::string r = read_block(q);
    check_errors(q);
    return r;
}

void Session::sync(double timeout_s) {
    const double saved = timeout_s_;
    timeout_s_ = timeout_s;
    try {
        send("*OPC?");
        const std::string r = read_line("*OPC?", kMaxReplyBytes);
        timeout_s_ = saved;
        if (r != "1" && r != "+1") throw DeviceError(uri_, link_->describe() + ": *OPC? answered " + cmd_quote(r) + " (expected 1)");
    } catch (...) {
        timeout_s_ = saved;
        throw;
    }
}

std::string Session::identify() {
    send("*IDN?");
    return term_escape(read_line("*IDN?", kMaxIdnBytes));
}

}  // namespace fringe::dev::scpi
