// Modbus boards over libmodbus (TCP and RTU): step mode only (a static sin/cos pair, settle,
// read back with averaging), the register map from a board profile (modbus_board.hpp).
// Native errors keep libmodbus's own text and name the board and register. The retry policy
// (docs/modbus.md "Timeouts, retries and reconnects"): a Modbus exception reply is final; a
// timeout, a garbled or stale reply (bad CRC, a transaction id or unit that is not ours) or a
// lost connection is retried up to `retries` times, over a fresh connection on TCP (a late
// reply to an abandoned request can then never be taken for the answer to a later one) or
// after draining the line on RTU. Every request has a deadline of (retries + 1) x timeout_ms
// (its attempts, reconnects and their backoff all inside it); each attempt's whole reply must
// arrive within timeout_ms (no per-byte allowance that a trickling reply could stretch); a
// block of 16 steps has a deadline too (below); a cancel is seen between attempts and during
// waits.
#include "device.hpp"
#include "modbus_board.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/constants.hpp"

#include <modbus/modbus.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>

namespace fringe::dev {

namespace {

using Clock = std::chrono::steady_clock;

bool connection_error(int e) {
    return e == ECONNRESET || e == EPIPE || e == EBADF || e == ECONNREFUSED || e == ENOTCONN || e == ECONNABORTED || e == EIO;
}

// A Modbus exception reply from the board (function code | 0x80): final, never retried. Other
// libmodbus codes above MODBUS_ENOBASE (bad CRC, invalid data such as a transaction id that is
// not ours, a reply from another unit, too many data) are a garbled or stale reply: retried.
bool exception_reply(int e) { return e >= EMBXILFUN && e <= EMBXGTAR; }

// Steps the run engine reads per block (server/engine/frame_source.cpp): the block deadline's unit.
constexpr int kBlockSteps = 16;

class ModbusDevice final : public Device, public StepPort, public RegisterPort {
public:
    ModbusDevice(const std::string& uri, const std::string& scheme, const std::string& path, const nlohmann::json& s)
        : uri_(uri), rtu_(scheme == "modbus+rtu") {
        const Params p(s);
        board_ = load_board(p.string("board"));
        unit_ = static_cast<int>(p.integer("unit"));
        timeout_ms_ = static_cast<int>(p.integer("timeout_ms"));
        retries_ = static_cast<int>(p.integer("retries"));
        settle_s_ = p.optional_number("settle_s").value_or(board_.settle_s);
        average_ = p.optional_number("average") ? static_cast<int>(*p.optional_number("average")) : board_.average;
        if (rtu_) {
            if (path.empty() || path[0] != '/') throw ConfigError("device", "modbus+rtu needs a serial device path: modbus+rtu:/dev/ttyUSB0?baud=115200");
            const std::string parity = p.string("parity");
            ctx_ = modbus_new_rtu(path.c_str(), static_cast<int>(p.integer("baud")), parity[0], static_cast<int>(p.integer("data_bits")),
                                  static_cast<int>(p.integer("stop_bits")));
            endpoint_ = path;
        } else {
            std::string hp = path.rfind("//", 0) == 0 ? path.substr(2) : path;
            const auto colon = hp.rfind(':');
            host_ = colon == std::string::npos ? hp : hp.substr(0, colon);
            int port = 502;
            if (colon != std::string::npos) {
                try {
                    port = std::stoi(hp.substr(colon + 1));
                } catch (const std::exception&) {
                    port = -1;
                }
            }
            if (host_.empty() || port <= 0 || port > 65535) throw ConfigError("device", "modbus+tcp needs host:port: modbus+tcp://192.168.1.50:502?board=NAME");
            ctx_ = modbus_new_tcp(host_.c_str(), port);
            endpoint_ = host_ + ":" + std::to_string(port);
        }
        if (!ctx_) throw DeviceError(uri_, std::string("libmodbus: ") + modbus_strerror(errno));
        modbus_set_slave(ctx_, unit_);
        set_timeout_ms(timeout_ms_);
        // No per-byte timeout: the whole reply must arrive within the response timeout (libmodbus's
        // select keeps counting the same interval down), so a reply trickled a byte at a time
        // cannot stretch one request beyond it.
        modbus_set_byte_timeout(ctx_, 0, 0);
        connect();
        try {
            open_board();
        } catch (...) {
            modbus_close(ctx_);
            modbus_free(ctx_);  // the constructor throws: no destructor will
            ctx_ = nullptr;
            throw;
        }
        std::vector<const RegisterDef*> readback;
        for (const char* role : {"sin_in", "cos_in", "position_count", "position_fraction", "position_rad", "status", "error_flags"})
            if (const auto* r = board_.find(role); r && r->readable) readback.push_back(r);
        batches_ = plan_reads(readback);
        sin_in_ = board_.find("sin_in");
        cos_in_ = board_.find("cos_in");
        pos_count_ = board_.find("position_count");
        pos_frac_ = board_.find("position_fraction");
        pos_rad_ = board_.find("position_rad");
        flags_ = board_.find("error_flags");
        // What each request is called in errors, built once (not per step).
        for (const auto& b : batches_) {
            std::string names;
            for (const auto* r : b.regs) names += (names.empty() ? "" : ",") + r->role;
            batch_what_.push_back(std::string("read ") + (b.table == RegTable::Input ? "input" : "holding") + " " + names + " @" +
                                  std::to_string(b.address) + "+" + std::to_string(b.count));
        }
        const auto* rs = sin_out_ = board_.find("sin_out");
        const auto* rc = cos_out_ = board_.find("cos_out");
        write_what_ = {"write sin_out,cos_out @" + std::to_string(rs->address), "write sin_out @" + std::to_string(rs->address),
                       "write cos_out @" + std::to_string(rc->address)};
        regs_.resize(2 * in_base_);  // holding image, then input image
    }
    void set_cancel(const std::atomic<bool>* cancel) override { cancel_ = cancel; }
    ~ModbusDevice() override {
        if (ctx_) {
            modbus_close(ctx_);
            modbus_free(ctx_);
        }
    }

    // Step mode only: a Modbus board has no streams, no generator memory and no digitizer.
    StepPort* step() override { return this; }
    RegisterPort* registers() override { return this; }

    // Raw register access (writing a correction), under the same retry policy as the steps.
    const BoardProfile& board() const override { return board_; }
    void write_words(int address, std::span<const std::uint16_t> w, int function, const std::string& what) override {
        if (function == 16) {
            with_retries(what, [&] { return modbus_write_registers(ctx_, address, static_cast<int>(w.size()), w.data()); });
            return;
        }
        for (std::size_t k = 0; k < w.size(); ++k)
            with_retries(what + " (function 6, register " + std::to_string(address + static_cast<int>(k)) + ")",
                         [&] { return modbus_write_register(ctx_, address + static_cast<int>(k), w[k]); });
    }
    void read_words(RegTable table, int address, int count, std::uint16_t* dst, const std::string& what) override {
        with_retries(what, [&] {
            const int n = table == RegTable::Input ? modbus_read_input_registers(ctx_, address, count, dst) : modbus_read_registers(ctx_, address, count, dst);
            if (n != -1 && n != count) {
                errno = EMBBADDATA;
                return -1;
            }
            return n;
        });
    }

    DeviceInfo describe() const override {
        DeviceInfo i;
        i.driver = "modbus";
        i.uri = uri_;
        i.description = board_.description.empty() ? "Modbus board " + board_.name : board_.description;
        i.board_id = board_.name + "@" + endpoint_ + "#" + std::to_string(unit_);
        i.dut_position = board_.has_dut_position();
        i.settings = {{"board", board_.name}, {"unit", unit_}, {"timeout_ms", timeout_ms_}, {"retries", retries_},
                      {"settle_s", settle_s_}, {"average", average_}, {"board_profile", board_.path}};
        // The profile's bits over range where given, else an integer register's scale (V per
        // count); a float register with neither is taken as ideal.
        const RegisterDef* dac = board_.find("sin_out");
        const RegisterDef* adc = board_.find("sin_in");
        i.converter.known = true;
        i.converter.dac_step_v = dac ? dac->step() : 0.0;
        i.converter.adc_step_v = adc ? adc->step() : 0.0;
        i.converter.dac_bits = dac ? dac->bits : 0;
        i.converter.adc_bits = adc ? adc->bits : 0;
        i.converter.dac_range_v = dac ? dac->symmetric_range() : 0.0;
        i.converter.adc_range_v = adc ? adc->symmetric_range() : 0.0;
        std::string from;
        for (const RegisterDef* r : {dac, adc})
            if (r && r->bits > 0)
                from += (from.empty() ? "" : ", ") + r->role + " " + std::to_string(r->bits) + " bits over " + num(r->range_lo) + ".." + num(r->range_hi) +
                        (r->unit.empty() ? "" : " " + r->unit) + " at the register";
        i.converter.note = (from.empty() ? "quantisation from the register scale" : "quantisation from the board profile (" + from + ")") +
                           std::string("; the board's analog noise is unknown");
        i.converter.added_noise_v = i.converter.independent_noise_v();
        return i;
    }

    StepResult measure(double sin_v, double cos_v, double settle_s, int average) override {
        if (settle_s < 0) settle_s = settle_s_;
        if (average <= 0) average = average_;
        // The block deadline: a block of 16 steps may take what its requests would if every one
        // used its whole timeout, plus one request's full retry budget. A board that answers
        // only after retries, request after request, ends the run here instead of stretching it
        // many times over.
        if (steps_ % kBlockSteps == 0) {
            const std::size_t writes = sin_out_->address + sin_out_->words() == cos_out_->address && sin_out_->write_function == 16 && cos_out_->write_function == 16
                                           ? 1 : static_cast<std::size_t>(sin_out_->words() + cos_out_->words());
            const double requests = static_cast<double>(writes + static_cast<std::size_t>(average) * batches_.size());
            block_budget_s_ = kBlockSteps * (settle_s + requests * timeout_ms_ * 1e-3) + (retries_ + 1) * timeout_ms_ * 1e-3;
            block_start_ = Clock::now();
            block_deadline_ = block_start_ + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(block_budget_s_));
            block_first_step_ = steps_;
        }
        ++steps_;
        // A board that came back after a lost connection may have restarted: its drive registers
        // and configuration are gone, so the identity checks and init writes run again and the
        // whole step is redone (never a reading of a drive value that was not written).
        for (int pass = 0;; ++pass) {
            const long long lost = lost_;
            StepResult out = step_once(sin_v, cos_v, settle_s, average);
            if (lost_ == lost) return out;
            if (pass >= retries_)
                throw DeviceError(uri_, "board " + board_.name + " at " + endpoint_ + ": the connection was lost and re-made " + std::to_string(pass + 1) +
                                            " times within one step (the board keeps restarting)");
            open_board();
        }
    }

private:
    StepResult step_once(double sin_v, double cos_v, double settle_s, int average) {
        write_pair(sin_v, cos_v);
        if (settle_s > 0) wait_s(settle_s, "settling");
        StepResult out;
        double ss = 0, cs = 0;
        std::optional<double> dut;
        bool dut_bad = false;
        for (int a = 0; a < average; ++a) {
            read_all();
            ++reads_;
            if (sin_in_) ss += read_input(*sin_in_);
            if (cos_in_) cs += read_input(*cos_in_);
            ++good_reads_;
        }
        out.sin_v = ss / average;
        out.cos_v = cs / average;
        // The DUT position of the last reading (angles are not averaged across a wrap).
        if (flags_) dut_bad = decode_register(*flags_, &regs_[key(*flags_)]) != 0;
        if (pos_rad_) dut = decode_register(*pos_rad_, &regs_[key(*pos_rad_)]);
        else if (pos_count_ && pos_frac_)
            dut = kTwoPi * (decode_register(*pos_count_, &regs_[key(*pos_count_)]) + decode_register(*pos_frac_, &regs_[key(*pos_frac_)]));
        if (dut && !dut_bad) out.dut_theta_rad = dut;  // a flagged reading is an invalid sample
        return out;
    }

    // One register image: holding registers at their address, input registers after them.
    std::size_t key(const RegisterDef& r) const { return r.table == RegTable::Input ? in_base_ + static_cast<std::size_t>(r.address) : static_cast<std::size_t>(r.address); }

    void set_timeout_ms(int ms) {
        ms = std::max(ms, 1);
        modbus_set_response_timeout(ctx_, static_cast<std::uint32_t>(ms / 1000), static_cast<std::uint32_t>((ms % 1000) * 1000));
    }

    void connect() {
        if (modbus_connect(ctx_) == -1) {
            const std::string msg = modbus_strerror(errno);
            modbus_free(ctx_);  // the constructor throws: no destructor will
            ctx_ = nullptr;
            throw DeviceError(uri_, "board " + board_.name + " at " + endpoint_ + ": connect: " + msg);
        }
        connected_ = true;
    }

    void check_cancel() const {
        if (cancel_ && cancel_->load()) throw Cancelled(uri_);
    }

    // Sleeps seconds in short slices, seeing a cancel within 20 ms.
    void wait_s(double seconds, const char*) const {
        const auto until = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
        for (;;) {
            check_cancel();
            const auto now = Clock::now();
            if (now >= until) return;
            std::this_thread::sleep_for(std::min<Clock::duration>(until - now, std::chrono::milliseconds(20)));
        }
    }

    static double ms_between(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

    // Runs op under the retry policy (top of the file). Throws naming the board, the request,
    // libmodbus's message, the attempts and the time spent.
    template <class Op>
    void with_retries(const std::string& what, Op&& op) {
        const auto t0 = Clock::now();
        const auto own = t0 + std::chrono::milliseconds(static_cast<long long>(timeout_ms_) * (retries_ + 1));
        const bool block = steps_ > 0 && block_deadline_ < own;
        const auto deadline = block ? block_deadline_ : own;
        int attempts = 0, refused = 0;
        int e = 0;
        auto backoff = std::chrono::milliseconds(50);
        auto fail = [&](const std::string& why) {
            std::string msg = "board " + board_.name + " at " + endpoint_ + ": " + what + ": " + why;
            if (!exception_reply(e) || attempts > 1) {
                char b[96];
                std::snprintf(b, sizeof b, " (after %d attempt%s%s in %.0f ms)", attempts, attempts == 1 ? "" : "s",
                              refused ? (", " + std::to_string(refused) + " refused reconnects").c_str() : "", ms_between(t0, Clock::now()));
                msg += b;
            }
            if (block && Clock::now() >= deadline) {
                char b[200];
                std::snprintf(b, sizeof b, "; steps %lld-%lld ran past their block deadline of %.3g s (16 steps, each request given its whole timeout_ms): the board answers late, request after request",
                              block_first_step_, block_first_step_ + kBlockSteps - 1, block_budget_s_);
                msg += b;
            }
            throw DeviceError(uri_, msg);
        };
        for (;;) {
            check_cancel();
            if (!connected_) {
                if (modbus_connect(ctx_) == 0) {
                    connected_ = true;
                    ++reconnects_;
                } else {
                    e = errno;
                    ++refused;
                    // Reconnect with backoff (50, 100, 200 ... 800 ms) while the deadline allows.
                    if (Clock::now() + backoff >= deadline) fail(std::string("reconnect: ") + modbus_strerror(e));
                    wait_s(std::chrono::duration<double>(backoff).count(), "reconnect backoff");
                    backoff = std::min(backoff * 2, std::chrono::milliseconds(800));
                    continue;
                }
            }
            const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
            if (left <= 0) fail(std::string(modbus_strerror(e ? e : ETIMEDOUT)));
            set_timeout_ms(static_cast<int>(std::min<long long>(timeout_ms_, left)));
            ++attempts;
            if (op() != -1) return;
            e = errno;
            if (exception_reply(e)) fail(modbus_strerror(e));
            if (attempts > retries_ || Clock::now() >= deadline) fail(modbus_strerror(e));
            // Whatever was late or garbled must not be read as the next reply: a fresh connection
            // on TCP; on RTU a quiet wait, then the line's input is discarded.
            if (!rtu_ || connection_error(e)) {
                if (connection_error(e)) ++lost_;  // the board may have restarted: the step is redone
                modbus_close(ctx_);
                connected_ = false;
            } else {
                wait_s(std::min(0.05, timeout_ms_ * 1e-3), "draining");
                modbus_flush(ctx_);
            }
        }
    }

    // Identity and word-order checks, then the configuration writes (a board that is not
    // what the profile says is not configured).
    void open_board() {
        for (const auto& c : board_.checks) {
            std::uint16_t w[2] = {0, 0};
            read_register(c.reg, w, "check " + c.reg.role + " @" + std::to_string(c.reg.address));
            const double got = decode_register(c.reg, w);
            if (std::fabs(got - c.expect) <= c.tolerance) continue;
            std::string msg = "board " + board_.name + " at " + endpoint_ + ": check " + c.reg.role + " @" + std::to_string(c.reg.address) + " reads " +
                              num(got) + ", expected " + num(c.expect) + (c.tolerance > 0 ? " +- " + num(c.tolerance) : "");
            if (!c.hint.empty()) msg += " (" + c.hint + ")";
            if (c.reg.words() == 2 && std::fabs(decode_swapped(c.reg, w) - c.expect) <= c.tolerance)
                msg += "; with the words swapped it reads " + num(c.expect) + ": the profile's word_order '" + (c.reg.low_word_first ? "little" : "big") +
                       "' is not the board's";
            throw DeviceError(uri_, msg);
        }
        for (const auto& iw : board_.init)
            write_register(iw.reg, encode_register(iw.reg, iw.value), "init " + iw.reg.role + "=" + num(iw.value) + " @" + std::to_string(iw.reg.address));
    }

    // One register's words with its write function: 16 in one request, 6 one request per word.
    void write_register(const RegisterDef& r, const std::vector<std::uint16_t>& w, const std::string& what) {
        if (r.write_function == 16) {
            with_retries(what, [&] { return modbus_write_registers(ctx_, r.address, static_cast<int>(w.size()), w.data()); });
            return;
        }
        for (std::size_t k = 0; k < w.size(); ++k)
            with_retries(what + " (function 6, word " + std::to_string(k) + ")", [&] { return modbus_write_register(ctx_, r.address + static_cast<int>(k), w[k]); });
    }

    void read_register(const RegisterDef& r, std::uint16_t* dst, const std::string& what) {
        with_retries(what, [&] {
            const int n = r.table == RegTable::Input ? modbus_read_input_registers(ctx_, r.address, r.words(), dst) : modbus_read_registers(ctx_, r.address, r.words(), dst);
            if (n != -1 && n != r.words()) {
                errno = EMBBADDATA;
                return -1;
            }
            return n;
        });
    }

    // A drive value outside the register's range would clip in the converter: an error, not
    // a silently distorted signal.
    std::vector<std::uint16_t> encode_checked(const RegisterDef& r, double v) const {
        const double raw = r.raw_of(v);
        if (r.has_range && !(raw >= r.range_lo && raw <= r.range_hi))
            throw DeviceError(uri_, "board " + board_.name + ": " + r.role + " = " + num(v) + " V needs " + num(raw) + " at register " + std::to_string(r.address) +
                                        ", outside its range " + num(r.range_lo) + ".." + num(r.range_hi) +
                                        " (the signal does not fit the converter: lower its amplitude or change the profile's offset)");
        return encode_register(r, v);
    }

    // A reading that is not a number, or far outside what the converter can return, is a
    // misread register (type, word order, address) when the board never read well; after good
    // readings it is the board's own fault at that reading, named with its count.
    double read_input(const RegisterDef& r) const {
        const std::uint16_t* w = &regs_[key(r)];
        const double v = decode_register(r, w);
        const double raw = r.raw_of(v);
        const double margin = r.has_range ? 0.1 * (r.range_hi - r.range_lo) : 0.0;
        if (!std::isfinite(v) || (r.has_range && (raw < r.range_lo - margin || raw > r.range_hi + margin))) {
            const std::string where = "board " + board_.name + " at " + endpoint_ + ": " + r.role + " @" + std::to_string(r.address);
            const std::string range = r.has_range ? " (its range " + num(r.range_lo) + ".." + num(r.range_hi) + ")" : "";
            if (good_reads_ > 0)
                throw DeviceError(uri_, where + " reads " + num(raw) + range + " at reading " + std::to_string(reads_) + ", after " + std::to_string(good_reads_) +
                                            " good readings: the board returned " + (std::isfinite(v) ? "a value far outside its range" : "a value that is not a number") +
                                            " (a fault or overrange of its converter, not the register map, which read well until now)");
            throw DeviceError(uri_, where + " reads " + num(raw) + (r.has_range ? ", far outside its range " + num(r.range_lo) + ".." + num(r.range_hi) : "") +
                                        " at the first reading: the register's type or word_order does not match the board (with the words swapped it reads " +
                                        num(r.raw_of(decode_swapped(r, w))) + ")");
        }
        return v;
    }

    void write_pair(double s, double c) {
        const auto& rs = *sin_out_;
        const auto& rc = *cos_out_;
        auto ws = encode_checked(rs, s), wc = encode_checked(rc, c);
        if (rc.address == rs.address + rs.words() && rs.write_function == 16 && rc.write_function == 16) {  // adjacent: one request
            ws.insert(ws.end(), wc.begin(), wc.end());
            with_retries(write_what_[0], [&] { return modbus_write_registers(ctx_, rs.address, static_cast<int>(ws.size()), ws.data()); });
        } else {
            write_register(rs, ws, write_what_[1]);
            write_register(rc, wc, write_what_[2]);
        }
    }

    void read_all() {
        for (std::size_t bi = 0; bi < batches_.size(); ++bi) {
            const auto& b = batches_[bi];
            std::uint16_t* dst = &regs_[b.table == RegTable::Input ? in_base_ + static_cast<std::size_t>(b.address) : static_cast<std::size_t>(b.address)];
            with_retries(batch_what_[bi], [&] {
                const int n = b.table == RegTable::Input ? modbus_read_input_registers(ctx_, b.address, b.count, dst)
                                                         : modbus_read_registers(ctx_, b.address, b.count, dst);
                if (n != -1 && n != b.count) {
                    errno = EMBBADDATA;
                    return -1;
                }
                return n;
            });
        }
    }

    std::string uri_, host_, endpoint_;
    bool rtu_;
    BoardProfile board_;
    int unit_ = 1, timeout_ms_ = 500, retries_ = 2, average_ = 1;
    double settle_s_ = 0;
    modbus_t* ctx_ = nullptr;
    bool connected_ = false;
    const std::atomic<bool>* cancel_ = nullptr;
    long long reconnects_ = 0, lost_ = 0, steps_ = 0, block_first_step_ = 0, reads_ = 0, good_reads_ = 0;
    double block_budget_s_ = 0;
    Clock::time_point block_start_{}, block_deadline_{};
    std::vector<ReadBatch> batches_;
    std::vector<std::string> batch_what_, write_what_;
    const RegisterDef *sin_out_ = nullptr, *cos_out_ = nullptr;
    const RegisterDef *sin_in_ = nullptr, *cos_in_ = nullptr, *pos_count_ = nullptr, *pos_frac_ = nullptr, *pos_rad_ = nullptr, *flags_ = nullptr;
    static constexpr std::size_t in_base_ = 65536 + 2;
    std::vector<std::uint16_t> regs_;
};

std::vector<ParamInfo> common_settings() {
    return {
        {"board", "", ParamType::String, "generic-aio", -kInf, kInf, {}, "board profile: a name in fixtures/boards/ (or $FRINGE_BOARDS), or a path"},
        {"unit", "", ParamType::Integer, 1, 0, 247, {}, "Modbus unit (slave) id"},
        {"timeout_ms", "ms", ParamType::Integer, 500, 1, 60000, {}, "response timeout per attempt: the whole reply must arrive within it"},
        {"retries", "", ParamType::Integer, 2, 0, 20, {}, "retries after a timeout, a garbled or stale reply or a lost connection (not after an exception reply); a request's deadline is (retries + 1) x timeout_ms"},
        {"settle_s", "s", ParamType::Number, nullptr, 0, 60, {}, "wait after writing a step before reading back (default: the board profile's)"},
        {"average", "", ParamType::Integer, nullptr, 1, 1000, {}, "readings averaged per step (default: the board profile's)"},
    };
}

}  // namespace

void register_modbus(std::vector<DriverInfo>& r) {
    DriverInfo tcp;
    tcp.scheme = "modbus+tcp";
    tcp.summary = "Modbus TCP board (libmodbus), step mode: modbus+tcp://host:port?unit=1&board=NAME";
    tcp.settings = common_settings();
    tcp.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        return std::make_unique<ModbusDevice>(uri, "modbus+tcp", path, s);
    };
    r.push_back(std::move(tcp));
    DriverInfo rtu;
    rtu.scheme = "modbus+rtu";
    rtu.summary = "Modbus RTU board on a serial port (libmodbus), step mode: modbus+rtu:/dev/ttyUSB0?baud=115200&board=NAME";
    rtu.settings = common_settings();
    rtu.settings.push_back({"baud", "Bd", ParamType::Integer, 115200, 300, 4000000, {}, "baud rate"});
    rtu.settings.push_back({"parity", "", ParamType::Choice, "N", -kInf, kInf, {"N", "E", "O"}, "parity"});
    rtu.settings.push_back({"data_bits", "bit", ParamType::Integer, 8, 5, 8, {}, "data bits"});
    rtu.settings.push_back({"stop_bits", "bit", ParamType::Integer, 1, 1, 2, {}, "stop bits"});
    rtu.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        return std::make_unique<ModbusDevice>(uri, "modbus+rtu", path, s);
    };
    r.push_back(std::move(rtu));
}

}  // namespace fringe::dev
