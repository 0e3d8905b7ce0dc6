// SCPI bench instruments (issue 14, docs/bench.md): arbitrary waveform generators (Keysight
// 33500B/33600A, Rigol DG800/DG900/DG1000Z, Siglent SDG, Red Pitaya) that play sin and cos
// from their memory, and digitizers (a generic `:WAV` scope readout, Red Pitaya acquisition)
// that record a block, over drivers/scpi.hpp (TCP or USBTMC). The dialects are kept apart from
// the transport, as libsigrok keeps protocol from transport.
//
// Start: a generator's play() uploads, sets rate/amplitude/offset, syncs its channels and
// arms them waiting for a bus trigger; a digitizer's record() arms its acquisition (triggered
// by the generator's sync/marker output on its EXT input, or Red Pitaya's internal AWG trigger)
// and then fires every generator armed in this process. So the record always holds the
// output's onset at a fixed delay (the alignment needs it); start=immediate plays at once for a
// digitizer fringe does not drive.
#include "device.hpp"
#include "scpi.hpp"
#include "signal_gen/base/text.hpp"
#include "signal_gen/base/config.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <mutex>
#include <thread>

namespace fringe::dev {

namespace {

using scpi::Session;

enum class Family { Keysight, Rigol, Siglent, RedPitaya, Scope };

struct Model {
    std::string name;
    Family family;
    bool generator, digitizer;
    std::size_t memory_samples;  // generator memory per channel (datasheet, standard option)
    double max_rate_hz;          // generator arb sample rate
    int dac_bits;
    double max_out_v;            // |offset| + Vpp/2 into high impedance
    std::string summary;
};

const std::vector<Model>& models() {
    static const std::vector<Model> m = {
        {"keysight-33500b", Family::Keysight, true, false, 1'000'000, 250e6, 16, 10.0, "Keysight/Agilent 33500B (1 MSa/ch standard)"},
        {"keysight-33600a", Family::Keysight, true, false, 4'000'000, 1e9, 14, 10.0, "Keysight 33600A (4 MSa/ch standard)"},
        {"rigol-dg800", Family::Rigol, true, false, 2'000'000, 200e6, 16, 10.0, "Rigol DG800"},
        {"rigol-dg900", Family::Rigol, true, false, 8'000'000, 250e6, 16, 10.0, "Rigol DG900"},
        {"rigol-dg1000z", Family::Rigol, true, false, 8'000'000, 60e6, 14, 10.0, "Rigol DG1000Z"},
        {"siglent-sdg", Family::Siglent, true, false, 8'000'000, 300e6, 16, 10.0, "Siglent SDG2000X/SDG6000X (TrueArb)"},
        {"redpitaya", Family::RedPitaya, true, true, 16384, 125e6, 14, 1.0, "Red Pitaya STEMlab (generator and acquisition, SCPI server)"},
        {"generic-scope", Family::Scope, false, true, 0, 0, 0, 0, "generic SCPI scope/digitizer (:WAV:DATA? readout)"},
    };
    return m;
}

const Model* find_model(const std::string& name) {
    for (const auto& m : models())
        if (m.name == name) return &m;
    return nullptr;
}

// *IDN? -> model, for model=auto.
const Model* model_from_idn(const std::string& idn) {
    std::string u = idn;
    std::transform(u.begin(), u.end(), u.begin(), [](unsigned char c) { return static_cast<char>(std::toupper(c)); });
    auto has = [&](const char* s) { return u.find(s) != std::string::npos; };
    if (has("REDPITAYA") || has("RED PITAYA")) return find_model("redpitaya");
    if ((has("KEYSIGHT") || has("AGILENT")) && (has(",335") || has(",336"))) return find_model(has(",336") ? "keysight-33600a" : "keysight-33500b");
    if (has("RIGOL") && has(",DG8")) return find_model("rigol-dg800");
    if (has("RIGOL") && has(",DG9")) return find_model("rigol-dg900");
    if (has("RIGOL") && has(",DG1") && has("Z")) return find_model("rigol-dg1000z");
    if (has("SIGLENT") && has(",SDG")) return find_model("siglent-sdg");
    return nullptr;
}

class ScpiInstrument;
// Generators armed in this process, waiting for the digitizer that records them.
std::mutex g_armed_mu;
std::vector<ScpiInstrument*> g_armed;

// A generator model has a play port, a digitizer model a record port, a Red Pitaya both;
// none streams or steps.
class ScpiInstrument final : public Device, public PlayPort, public RecordPort {
public:
    ScpiInstrument(const std::string& uri, const std::string& scheme, const std::string& path, const nlohmann::json& s) : uri_(uri) {
        const Params p(s);
        timeout_s_ = p.number("timeout_s");
        start_ = p.string("start");
        trigger_ = p.string("trigger");
        pretrigger_ = static_cast<std::size_t>(p.integer("pretrigger_samples"));
        scope_format_ = p.string("format");
        chunk_ = static_cast<std::size_t>(p.integer("chunk_points"));
        std::unique_ptr<scpi::Link> link;
        try {
            if (scheme == "scpi+tcp") {
                std::string hp = path.rfind("//", 0) == 0 ? path.substr(2) : path;
                const auto colon = hp.rfind(':');
                int port = -1;
                if (colon != std::string::npos) {
                    try {
                        port = std::stoi(hp.substr(colon + 1));
                    } catch (const std::exception&) {
                    }
                }
                const std::string host = colon == std::string::npos ? hp : hp.substr(0, colon);
                if (host.empty() || port <= 0 || port > 65535)
                    throw ConfigError("device", "scpi+tcp needs host:port: scpi+tcp://192.168.1.20:5025?model=keysight-33500b");
                endpoint_ = host + ":" + std::to_string(port);
                link = scpi::connect_tcp(host, port, timeout_s_);
            } else {
                unsigned vid = 0, pid = 0;
                char tail = 0;
                if (std::sscanf(path.c_str(), "%x:%x%c", &vid, &pid, &tail) != 2 || vid > 0xFFFF || pid > 0xFFFF)
                    throw ConfigError("device", "scpi+usbtmc needs VID:PID in hex: scpi+usbtmc:0957:2c07?model=keysight-33500b");
                endpoint_ = path;
                link = scpi::open_usbtmc(static_cast<std::uint16_t>(vid), static_cast<std::uint16_t>(pid), p.string("serial"), timeout_s_);
            }
        } catch (const ConfigError&) {
            throw;
        } catch (const std::exception& e) {
            throw DeviceError(uri_, e.what());
        }
        max_block_ = 512u << 20;
        io_ = std::make_unique<Session>(std::move(link), uri_, timeout_s_, max_block_);
        io_->error_queue = p.integer("error_queue") != 0;
        idn_ = io_->identify();
        const std::string want = p.string("model");
        model_ = want == "auto" ? model_from_idn(idn_) : find_model(want);
        if (!model_)
            throw DeviceError(uri_, "*IDN? says '" + idn_ + "', which is no known instrument: name it with model=" + model_names());
        memory_ = p.integer("memory_samples") > 0 ? static_cast<std::size_t>(p.integer("memory_samples")) : model_->memory_samples;
        io_->command("*CLS");
    }
    // Never throws: it runs while a failure unwinds. The frame source has already tried to stop
    // the output and logged why it could not; this is the last, silent attempt.
    ~ScpiInstrument() override {
        try {
            disarm();
            if (playing_) stop_output();
        } catch (...) {  // the instrument may be gone: nothing more to do
        }
    }

    static std::string model_names() {
        std::string s;
        for (const auto& m : models()) s += (s.empty() ? "" : "|") + m.name;
        return s;
    }

    PlayPort* player() override { return model_->generator ? this : nullptr; }
    // No family fringe drives can play non-repeating data beyond its memory over SCPI, so none
    // has a SequencePort (docs/bench.md "Segmented playback"): why, per family.
    std::string sequence_refusal() const override {
        switch (model_->family) {
            case Family::Keysight:
                return "the " + model_->name + "'s arb sequences (DATA:SEQuence) play segments that are all held in its waveform memory at once, so a sequence of "
                       "distinct segments is no longer than that memory; with a larger memory option set memory_samples";
            case Family::Rigol:
                return "the " + model_->name + "'s sequence mode plays waveforms held in its internal memory together and takes no new data while it plays";
            case Family::Siglent: return "the " + model_->name + " has no sequence or streaming mode for TrueArb waveforms over SCPI";
            case Family::RedPitaya:
                return "the Red Pitaya SCPI server's generator holds 16384 samples per channel; its DAC streaming runs through the streaming server's own "
                       "protocol, not SCPI, which fringe does not drive";
            case Family::Scope: break;
        }
        return "not a generator";
    }
    RecordPort* recorder() override { return model_->digitizer ? this : nullptr; }

    DeviceInfo describe() const override {
        DeviceInfo i;
        i.driver = "scpi";
        i.uri = uri_;
        i.description = model_->summary + " at " + endpoint_ + " (" + idn_ + ")";
        i.board_id = idn_;
        i.own_clock = true;
        i.settings = {{"model", model_->name}, {"timeout_s", timeout_s_}, {"start", start_}, {"trigger", trigger_},
                      {"pretrigger_samples", pretrigger_}, {"memory_samples", memory_}, {"idn", idn_}};
        i.converter.known = false;
        i.converter.dac_bits = model_->dac_bits;
        i.converter.note = "instrument converter noise not modelled; the run measures it through the alignment residual";
        return i;
    }

    // ---- generator ----
    void play(std::span<const double> s, std::span<const double> c, double fs, bool cyclic) override {
        if (s.size() != c.size() || s.size() < 2) throw DeviceError(uri_, "play needs two channels of equal length (at least 2 samples)");
        if (memory_ && s.size() > memory_)
            throw DeviceError(uri_, std::to_string(s.size()) + " samples per channel exceed the generator's memory of " + std::to_string(memory_) +
                                        " (memory_samples)");
        if (!(fs > 0) || fs > model_->max_rate_hz)
            throw DeviceError(uri_, "sample rate " + num(fs) + " Hz is outside the " + model_->name + "'s 0.." + num(model_->max_rate_hz) + " Hz");
        for (std::span<const double> ch : {s, c})
            for (double v : ch)
                if (!std::isfinite(v)) throw DeviceError(uri_, "play: a sample is not finite");
        disarm();
        cyclic_ = cyclic;
        for (int ch = 1; ch <= 2; ++ch) {
            const auto v = ch == 1 ? s : c;
            const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
            Scale sc;
            sc.offset_v = (*hi + *lo) / 2;
            sc.vpp = std::max(*hi - *lo, 2e-3);  // generators refuse a zero amplitude
            if (std::fabs(sc.offset_v) + sc.vpp / 2 > model_->max_out_v + 1e-12)
                throw DeviceError(uri_, "channel " + std::to_string(ch) + " spans " + num(*lo) + ".." + num(*hi) + " V, beyond the " + model_->name + "'s +-" +
                                            num(model_->max_out_v) + " V");
            switch (model_->family) {
                case Family::Keysight: upload_keysight(ch, v, sc, fs); break;
                case Family::Rigol: upload_rigol(ch, v, sc, fs); break;
                case Family::Siglent: upload_siglent(ch, v, sc, fs); break;
                case Family::RedPitaya: upload_redpitaya(ch, v, sc, fs); break;
                case Family::Scope: break;
            }
        }
        // Phase alignment between the channels, then outputs on, waiting for the trigger.
        switch (model_->family) {
            case Family::Keysight: io_->command("FUNC:ARB:SYNC"); io_->command("OUTP1 ON"); io_->command("OUTP2 ON"); break;
            case Family::Rigol: io_->command(":OUTP1 ON"); io_->command(":OUTP2 ON"); io_->command(":SOUR1:PHAS:SYNC"); break;
            case Family::Siglent: io_->command("MODE PHASE-LOCKED"); io_->command("C1:OUTP ON"); io_->command("C2:OUTP ON"); break;
            case Family::RedPitaya: io_->command("OUTPUT:STATE ON"); break;
            case Family::Scope: break;
        }
        io_->sync(timeout_s_);
        playing_ = true;
        if (start_ == "immediate") {
            fire();
        } else {
            std::lock_guard<std::mutex> lk(g_armed_mu);
            g_armed.push_back(this);
            armed_ = true;
        }
    }

    std::size_t memory_samples() const override { return memory_; }

    void stop_output() override {
        disarm();
        if (!playing_) return;
        playing_ = false;
        switch (model_->family) {
            case Family::Keysight: io_->command("OUTP1 OFF"); io_->command("OUTP2 OFF"); break;
            case Family::Rigol: io_->command(":OUTP1 OFF"); io_->command(":OUTP2 OFF"); break;
            case Family::Siglent: io_->command("C1:OUTP OFF"); io_->command("C2:OUTP OFF"); break;
            case Family::RedPitaya: io_->command("OUTPUT:STATE OFF"); break;
            case Family::Scope: break;
        }
    }

    // The bus trigger that starts both channels at once.
    void fire() {
        switch (model_->family) {
            case Family::Keysight:
            case Family::Rigol: io_->command("*TRG"); break;
            case Family::Siglent: io_->command("C1:BTWV MTRIG"); break;
            case Family::RedPitaya: io_->command("SOUR:TRIG:INT"); break;
            case Family::Scope: break;
        }
    }

    // ---- digitizer ----
    StreamResult record(std::span<double> s, std::span<double> c, double fs, double timeout_s) override {
        if (s.size() != c.size() || s.empty()) throw DeviceError(uri_, "record needs two channel buffers of equal, non-zero length");
        try {
            return model_->family == Family::RedPitaya ? record_redpitaya(s, c, fs, timeout_s) : record_scope(s, c, fs, timeout_s);
        } catch (const scpi::InstrumentTimeout& e) {
            return {StreamStatus::Timeout, 0, 0, 0, e.what()};
        }
    }

private:
    struct Scale {
        double offset_v = 0, vpp = 1;
        double norm(double v) const { return std::clamp((v - offset_v) / (vpp / 2), -1.0, 1.0); }
    };

    void disarm() {
        if (!armed_) return;
        std::lock_guard<std::mutex> lk(g_armed_mu);
        g_armed.erase(std::remove(g_armed.begin(), g_armed.end(), this), g_armed.end());
        armed_ = false;
    }
    // Starts every generator armed in this process (after the digitizer is armed).
    static void fire_armed() {
        std::vector<ScpiInstrument*> armed;
        {
            std::lock_guard<std::mutex> lk(g_armed_mu);
            armed.swap(g_armed);
        }
        for (auto* g : armed) {
            g->armed_ = false;
            g->fire();
        }
    }

    void set_amplitude(const std::string& pre, const Scale& sc, const std::string& volt, const std::string& offs) {
        // Offset to 0 first: amplitude and offset are coupled by the output limits.
        io_->command(pre + offs + " 0");
        io_->command(pre + volt + " " + num(sc.vpp));
        io_->command(pre + offs + " " + num(sc.offset_v));
    }

    // Keysight 33500B/33600A Operating and Service Guide, "DATA:ARBitrary[1|2]:DAC", "FUNCtion:ARBitrary:SRATe",
    // "FUNCtion:ARBitrary:SYNChronize", "BURSt" and "TRIGger" subsystems.
    void upload_keysight(int ch, std::span<const double> v, const Scale& sc, double fs) {
        const std::string src = "SOUR" + std::to_string(ch) + ":", name = ch == 1 ? "FRINGE_SIN" : "FRINGE_COS";
        std::string data(v.size() * 2, '\0');
        for (std::size_t k = 0; k < v.size(); ++k) {
            const auto code = static_cast<std::int16_t>(std::lround(sc.norm(v[k]) * 32767));
            data[2 * k] = static_cast<char>(code & 0xFF);  // FORM:BORD SWAP: little-endian
            data[2 * k + 1] = static_cast<char>((code >> 8) & 0xFF);
        }
        io_->command("FORM:BORD SWAP");
        io_->command(src + "DATA:VOL:CLE");
        io_->command(src + "DATA:ARB:DAC " + name + "," + scpi::encode_block(data));
        io_->command(src + "FUNC ARB");
        io_->command(src + "FUNC:ARB " + name);
        io_->command(src + "FUNC:ARB:SRAT " + num(fs));
        set_amplitude(src, sc, "VOLT", "VOLT:OFFS");
        io_->command(src + "BURS:MODE TRIG");
        io_->command(src + "BURS:NCYC " + std::string(cyclic_ ? "INF" : "1"));
        io_->command("TRIG" + std::to_string(ch) + ":SOUR BUS");
        io_->command(src + "BURS:STAT ON");
    }

    // Rigol DG1000Z/DG800/DG900 Programming Guide, ":TRACe:DATA:DAC16" (14/16-bit codes, at most
    // 16384 points per packet, CON/END), ":APPLy:ARBitrary", ":BURSt", ":PHASe:SYNChronize".
    void upload_rigol(int ch, std::span<const double> v, const Scale& sc, double fs) {
        const std::string src = ":SOUR" + std::to_string(ch) + ":";
        const double full = model_->dac_bits == 14 ? 16383.0 : 65535.0;
        io_->command(src + "APPL:ARB " + num(fs));
        constexpr std::size_t kPacket = 16384;
        for (std::size_t k0 = 0; k0 < v.size(); k0 += kPacket) {
            const std::size_t n = std::min(kPacket, v.size() - k0);
            std::string data(n * 2, '\0');
            for (std::size_t k = 0; k < n; ++k) {
                const auto code = static_cast<std::uint16_t>(std::lround((sc.norm(v[k0 + k]) + 1) / 2 * full));
                data[2 * k] = static_cast<char>(code & 0xFF);  // little-endian
                data[2 * k + 1] = static_cast<char>(code >> 8);
            }
            io_->command(src + "TRAC:DATA:DAC16 VOLATILE," + (k0 + n == v.size() ? "END," : "CON,") + scpi::encode_block(data));
        }
        io_->command(src + "FUNC:ARB:SRAT " + num(fs));
        set_amplitude(src, sc, "VOLT", "VOLT:OFFS");
        io_->command(src + "BURS:STAT ON");
        io_->command(src + "BURS:MODE " + std::string(cyclic_ ? "INF" : "TRIG"));
        io_->command(src + "BURS:NCYC 1");
        io_->command(src + "BURS:TRIG:SOUR MAN");
    }

    // Siglent SDG Series Programming Guide: "WVDT" (16-bit signed, little-endian, raw after
    // WAVEDATA,), "ARWV", "SRATE" (TrueArb), "BTWV", "MODE PHASE-LOCKED".
    void upload_siglent(int ch, std::span<const double> v, const Scale& sc, double fs) {
        const std::string cn = "C" + std::to_string(ch) + ":", name = ch == 1 ? "fringe_sin" : "fringe_cos";
        std::string data(v.size() * 2, '\0');
        for (std::size_t k = 0; k < v.size(); ++k) {
            const auto code = static_cast<std::int16_t>(std::lround(sc.norm(v[k]) * 32767));
            data[2 * k] = static_cast<char>(code & 0xFF);
            data[2 * k + 1] = static_cast<char>((code >> 8) & 0xFF);
        }
        io_->command(cn + "WVDT WVNM," + name + ",LENGTH," + std::to_string(data.size()) + ",FREQ," + num(fs / static_cast<double>(v.size())) + ",AMPL," +
                     num(sc.vpp) + ",OFST," + num(sc.offset_v) + ",PHASE,0,WAVEDATA," + data);
        io_->command(cn + "ARWV NAME," + name);
        io_->command(cn + "SRATE MODE,TARB,VALUE," + num(fs));
        io_->command(cn + "BSWV AMP," + num(sc.vpp) + ",OFST," + num(sc.offset_v));
        io_->command(cn + "BTWV STATE,ON,TRSR,MAN,GATE_NCYC,NCYC,TIME," + std::string(cyclic_ ? "INF" : "1"));
    }

    // Red Pitaya SCPI server (redpitaya.readthedocs.io, "Signal generator"): normalised floats
    // in SOUR<n>:TRAC:DATA:DATA (16384 samples), FREQ:FIX = one pass of the buffer, VOLT is the
    // amplitude (half Vpp), burst or continuous, SOUR:TRIG:INT starts both channels.
    void upload_redpitaya(int ch, std::span<const double> v, const Scale& sc, double fs) {
        const std::string src = "SOUR" + std::to_string(ch) + ":";
        if (ch == 1) io_->command("GEN:RST");
        io_->command(src + "FUNC ARBITRARY");
        std::string list;
        list.reserve(v.size() * 10);
        char b[32];
        for (std::size_t k = 0; k < v.size(); ++k) {
            std::snprintf(b, sizeof b, "%s%.6f", k ? "," : "", sc.norm(v[k]));
            list += b;
        }
        io_->command(src + "TRAC:DATA:DATA " + list);
        io_->command(src + "FREQ:FIX " + num(fs / static_cast<double>(v.size())));
        io_->command(src + "VOLT:OFFS 0");
        io_->command(src + "VOLT " + num(sc.vpp / 2));
        io_->command(src + "VOLT:OFFS " + num(sc.offset_v));
        if (cyclic_) {
            io_->command(src + "BURS:STAT CONTINUOUS");
        } else {
            io_->command(src + "BURS:STAT BURST");
            io_->command(src + "BURS:NCYC 1");
            io_->command(src + "BURS:NOR 1");
        }
        io_->command(src + "TRIG:SOUR INT");
    }

    // Waits until done() or the deadline; false on the deadline.
    template <class F>
    bool poll_until(double timeout_s, F&& done) {
        const auto dl = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
        for (;;) {
            if (done()) return true;
            if (std::chrono::steady_clock::now() > dl) return false;
            std::this_thread::sleep_for(std::chrono::milliseconds(5));
        }
    }

    // Generic scope/digitizer: Rigol DS/MSO and Keysight InfiniiVision style acquisition and
    // readout (":ACQ:SRAT", ":ACQ:POIN", ":TRIG:SOUR EXT", ":SING", ":TRIG:STAT?", ":WAV:SOUR",
    // ":WAV:FORM BYTE|WORD", ":WAV:PRE?", ":WAV:STAR/STOP", ":WAV:DATA?").
    StreamResult record_scope(std::span<double> s, std::span<double> c, double fs, double timeout_s) {
        const std::size_t M = s.size();
        io_->command(":STOP");
        io_->command(":ACQ:SRAT " + num(fs));
        const double got_fs = std::strtod(io_->query(":ACQ:SRAT?").c_str(), nullptr);
        if (!(std::fabs(got_fs - fs) <= 1e-9 * fs))
            throw DeviceError(uri_, "asked for " + num(fs) + " Sa/s, the digitizer runs at " + num(got_fs) + " Sa/s: choose a sample_rate_hz it supports");
        io_->command(":ACQ:POIN " + std::to_string(M));
        const bool ext = trigger_ != "now";
        io_->command(std::string(":TRIG:SOUR ") + (ext ? "EXT" : "IMM"));
        io_->command(":TRIG:POS " + std::to_string(std::min(pretrigger_, M)));
        io_->command(":SING");
        io_->sync(timeout_s_);
        fire_armed();
        std::string st;
        if (!poll_until(timeout_s, [&] { return (st = io_->query(":TRIG:STAT?")) == "STOP"; }))
            return {StreamStatus::Timeout, 0, 0, 0,
                    "no complete acquisition within " + num(timeout_s) + " s (trigger state " + term_escape(st.substr(0, 60)) + ")" +
                        (ext ? ": no trigger on EXT? wire the generator's sync/marker output to the digitizer's external trigger input" : "")};
        const bool word = scope_format_ == "word";
        for (int ch = 1; ch <= 2; ++ch) {
            auto out = ch == 1 ? s : c;
            io_->command(":WAV:SOUR CHAN" + std::to_string(ch));
            io_->command(std::string(":WAV:FORM ") + (word ? "WORD" : "BYTE"));
            if (word) io_->command(":WAV:BYT LSBF");
            io_->command(":WAV:MODE RAW");
            const auto pre = parse_preamble(io_->query(":WAV:PRE?"), M, fs);
            for (std::size_t k0 = 0; k0 < M; k0 += chunk_) {
                const std::size_t n = std::min(chunk_, M - k0);
                io_->command(":WAV:STAR " + std::to_string(k0 + 1));
                io_->command(":WAV:STOP " + std::to_string(k0 + n));
                const std::string b = io_->query_block(":WAV:DATA?");
                if (b.size() != n * (word ? 2 : 1))
                    throw DeviceError(uri_, ":WAV:DATA? for points " + std::to_string(k0 + 1) + ".." + std::to_string(k0 + n) + " returned " + std::to_string(b.size()) +
                                                " bytes, expected " + std::to_string(n * (word ? 2 : 1)));
                for (std::size_t k = 0; k < n; ++k) {
                    const double code = word ? static_cast<double>(static_cast<std::uint8_t>(b[2 * k]) | (static_cast<std::uint8_t>(b[2 * k + 1]) << 8))
                                             : static_cast<double>(static_cast<std::uint8_t>(b[k]));
                    out[k0 + k] = (code - pre.yorig - pre.yref) * pre.yinc;
                }
            }
        }
        return {StreamStatus::Ok, M, 0, 0, ""};
    }

    struct Preamble {
        double yinc = 0, yorig = 0, yref = 0;
    };
    // format,type,points,count,xincrement,xorigin,xreference,yincrement,yorigin,yreference
    Preamble parse_preamble(const std::string& r, std::size_t M, double fs) {
        std::vector<double> f;
        const char* p = r.c_str();
        while (*p) {
            char* end = nullptr;
            const double v = std::strtod(p, &end);
            if (end == p) break;
            f.push_back(v);
            p = end;
            while (*p == ',' || *p == ' ') ++p;
        }
        if (f.size() != 10 || *p) throw DeviceError(uri_, ":WAV:PRE? answered '" + term_escape(r.substr(0, 120)) + "': expected 10 comma-separated numbers");
        for (double v : f)
            if (!std::isfinite(v)) throw DeviceError(uri_, ":WAV:PRE? has a non-finite field: '" + term_escape(r.substr(0, 120)) + "'");
        if (f[2] < static_cast<double>(M)) throw DeviceError(uri_, ":WAV:PRE? holds " + num(f[2]) + " points, fewer than the " + std::to_string(M) + " asked for");
        if (!(f[7] > 0)) throw DeviceError(uri_, ":WAV:PRE? yincrement " + num(f[7]) + " is not positive");
        if (std::fabs(f[4] * fs - 1) > 1e-6) throw DeviceError(uri_, ":WAV:PRE? xincrement " + num(f[4]) + " s does not match " + num(fs) + " Sa/s");
        return {f[7], f[8], f[9]};
    }

    // Red Pitaya acquisition (redpitaya.readthedocs.io, "Acquisition"): 125 MSa/s / decimation,
    // a 16384-sample buffer with the trigger at sample 8192 - ACQ:TRIG:DLY, volts as ASCII.
    StreamResult record_redpitaya(std::span<double> s, std::span<double> c, double fs, double timeout_s) {
        constexpr std::size_t kBuffer = 16384;
        const std::size_t M = s.size();
        if (M > kBuffer) throw DeviceError(uri_, "Red Pitaya acquisition holds 16384 samples; " + std::to_string(M) + " asked (shorten duration_s or lower sample_rate_hz)");
        const double dec = 125e6 / fs;
        if (std::fabs(dec - std::round(dec)) > 1e-9 * dec || dec < 1 || dec > 65536)
            throw DeviceError(uri_, "Red Pitaya samples at 125 MHz / decimation (1..65536): " + num(fs) + " Sa/s is not one (try " + num(125e6 / std::max(1.0, std::round(dec))) + ")");
        const auto d = static_cast<long>(std::lround(dec));
        io_->command("ACQ:RST");
        io_->command((d & (d - 1)) == 0 ? "ACQ:DEC " + std::to_string(d) : "ACQ:DEC:F " + std::to_string(d));
        io_->command("ACQ:DATA:UNITS VOLTS");
        io_->command("ACQ:DATA:FORMAT ASCII");
        const std::size_t pre = std::min(pretrigger_, M);
        io_->command("ACQ:TRIG:DLY " + std::to_string(static_cast<long>(kBuffer / 2) - static_cast<long>(pre)));
        io_->command("ACQ:START");
        std::string src = trigger_ == "now" ? "NOW" : trigger_ == "ext" ? "EXT_PE" : trigger_ == "awg" ? "AWG_PE" : (playing_ ? "AWG_PE" : "EXT_PE");
        io_->command("ACQ:TRIG " + src);
        fire_armed();
        std::string st;
        if (!poll_until(timeout_s, [&] { return (st = io_->query("ACQ:TRIG:STAT?")) == "TD"; }))
            return {StreamStatus::Timeout, 0, 0, 0, "no trigger (" + src + ") within " + num(timeout_s) + " s (ACQ:TRIG:STAT? " + term_escape(st.substr(0, 60)) + ")"};
        if (!poll_until(timeout_s, [&] { return io_->query("ACQ:TRIG:FILL?") == "1"; }))
            return {StreamStatus::Timeout, 0, 0, 0, "the acquisition buffer did not fill within " + num(timeout_s) + " s"};
        for (int ch = 1; ch <= 2; ++ch) {
            auto out = ch == 1 ? s : c;
            // 16384 ASCII volts: a few hundred KiB; 4 MiB is the most this reply may be.
            const std::string r = io_->query("ACQ:SOUR" + std::to_string(ch) + ":DATA?", 4u << 20);
            // {v,v,...}: the buffer from the oldest sample, trigger at 8192 - DLY.
            std::size_t k = 0;
            const char* p = r.c_str();
            if (*p == '{') ++p;
            while (*p && *p != '}' && k < kBuffer) {
                char* end = nullptr;
                const double v = std::strtod(p, &end);
                if (end == p || !std::isfinite(v)) throw DeviceError(uri_, "ACQ:SOUR" + std::to_string(ch) + ":DATA? sample " + std::to_string(k) + " is not a number");
                if (k < M) out[k] = v;
                ++k;
                p = end;
                if (*p == ',') ++p;
            }
            if (k < M) throw DeviceError(uri_, "ACQ:SOUR" + std::to_string(ch) + ":DATA? returned " + std::to_string(k) + " samples, fewer than " + std::to_string(M));
        }
        return {StreamStatus::Ok, M, 0, 0, ""};
    }

    std::string uri_, endpoint_, idn_, start_, trigger_, scope_format_;
    const Model* model_ = nullptr;
    std::unique_ptr<Session> io_;
    double timeout_s_ = 5;
    std::size_t memory_ = 0, pretrigger_ = 0, chunk_ = 250000, max_block_ = 0;
    bool cyclic_ = false, playing_ = false, armed_ = false;
};

std::vector<ParamInfo> common_settings() {
    std::vector<std::string> names{"auto"};
    for (const auto& m : models()) names.push_back(m.name);
    return {
        {"model", "", ParamType::Choice, "auto", -kInf, kInf, names, "instrument dialect (auto: from *IDN?; a scope/digitizer must be named: generic-scope)"},
        {"timeout_s", "s", ParamType::Number, 5.0, 0.01, 600, {}, "reply timeout per command"},
        {"start", "", ParamType::Choice, "digitizer", -kInf, kInf, {"digitizer", "immediate"},
         "generator: wait for the digitizer fringe records with (it fires the bus trigger once armed), or play at once"},
        {"trigger", "", ParamType::Choice, "auto", -kInf, kInf, {"auto", "ext", "awg", "now"},
         "digitizer trigger: ext (generator sync -> EXT in), awg (Red Pitaya's own generator), now; auto: awg for a Red Pitaya that also plays, else ext"},
        {"pretrigger_samples", "samples", ParamType::Integer, 256, 0, 1e9, {}, "digitizer samples recorded before the trigger"},
        {"memory_samples", "samples", ParamType::Integer, 0, 0, 1e10, {}, "generator memory per channel (0: the model's standard memory)"},
        {"format", "", ParamType::Choice, "word", -kInf, kInf, {"word", "byte"}, "generic-scope :WAV:FORM (16- or 8-bit codes)"},
        {"chunk_points", "points", ParamType::Integer, 250000, 1000, 1e8, {}, "generic-scope points per :WAV:DATA? read"},
        {"error_queue", "", ParamType::Integer, 1, 0, 1, {}, "read SYST:ERR? after every command (0: for an instrument without an error queue)"},
    };
}

}  // namespace

void register_scpi(std::vector<DriverInfo>& r) {
    DriverInfo tcp;
    tcp.scheme = "scpi+tcp";
    tcp.summary = "SCPI instrument over a raw TCP socket (docs/bench.md): scpi+tcp://HOST:5025?model=keysight-33500b (generators play, digitizers record)";
    tcp.settings = common_settings();
    tcp.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        return std::make_unique<ScpiInstrument>(uri, "scpi+tcp", path, s);
    };
    r.push_back(std::move(tcp));
    DriverInfo usb;
    usb.scheme = "scpi+usbtmc";
    usb.summary = "SCPI instrument over USBTMC (libusb; not tried on hardware, docs/bench.md): scpi+usbtmc:VID:PID?serial=...&model=...";
    usb.settings = common_settings();
    usb.settings.push_back({"serial", "", ParamType::String, "", -kInf, kInf, {}, "only the instrument with this USB serial number"});
    usb.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        return std::make_unique<ScpiInstrument>(uri, "scpi+usbtmc", path, s);
    };
    r.push_back(std::move(usb));
}

}  // namespace fringe::dev
