// instrument-sim dialect: Red Pitaya STEMlab over its SCPI server: the generator (SOUR: arbitrary buffer of 16384
// points, frequency of one pass, internal trigger) and the acquisition (ACQ: decimation,
// trigger source and delay, buffer readout in volts or raw), one instrument on one port.
#include "drivers/sim/instrument_sim_core.hpp"

namespace fringe::dev::isim {

bool Sim::redpitaya_gen(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
    int ch = -1;
    auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
    if (is("GEN:RST")) {
        gen_.reset();
        return true;
    }
    if (is("SOUR#:FUNC")) {
        chan(ch);
        if (q) r = "ARBITRARY";
        return true;
    }
    if (is("SOUR#:TRAC:DATA:DATA")) {
        auto& c = chan(ch);
        std::vector<double> v;
        for (const auto& x : split_commas(a)) {
            const double f = parse_number(x);
            if (f < -1 || f > 1) err(-222, "Data out of range");
            v.push_back(f);
        }
        if (v.size() > 16384) err(-222, "Data out of range;the buffer holds 16384 samples");
        if (v.size() < 2) err(-222, "Data out of range");
        c.norm = std::move(v);
        c.start_s.reset();
        return true;
    }
    if (is("SOUR#:FREQ:FIX")) {
        auto& c = chan(ch);
        if (q) r = fmt(c.rp_freq_hz);
        else {
            const double f = parse_number(a);
            if (f <= 0 || f > 62.5e6) err(-222, "Data out of range");
            c.rp_freq_hz = f;
        }
        return true;
    }
    if (is("SOUR#:VOLT:OFFS") || is("SOUR#:VOLT")) {
        auto& c = chan(ch);
        const bool offs = h.back().name == "OFFS";
        if (q) {
            r = fmt(offs ? c.offset_v : c.vpp / 2);
            return true;
        }
        const double ov = c.vpp, oo = c.offset_v, v = parse_number(a);
        if (offs) c.offset_v = v;
        else c.vpp = 2 * v;  // VOLT is the amplitude
        try {
            check_levels(c);
        } catch (...) {
            c.vpp = ov, c.offset_v = oo;
            throw;
        }
        return true;
    }
    if (is("SOUR#:BURS:STAT")) {
        auto& c = chan(ch);
        const auto u = upper(trim(a));
        if (u != "BURST" && u != "CONTINUOUS") err(-224, "Illegal parameter value");
        c.burst = u == "BURST";
        c.infinite = !c.burst;
        return true;
    }
    if (is("SOUR#:BURS:NCYC") || is("SOUR#:BURS:NOR")) {
        chan(ch);
        if (parse_number(a) != 1) err(-222, "Data out of range;the emulator plays one burst of one cycle");
        return true;
    }
    if (is("SOUR#:TRIG:SOUR")) {
        chan(ch).trig_source = upper(trim(a)) == "INT" ? "BUS" : upper(trim(a));
        return true;
    }
    if (is("SOUR#:TRIG:INT")) {  // SOUR:TRIG:INT: both channels at once
        trigger({ch != 2, ch == -1 || ch == 2}, false);
        return true;
    }
    if (is("OUTP#:STAT")) {
        if (q) {
            r = chan(ch).output ? "ON" : "OFF";
            return true;
        }
        const bool on = parse_bool(a);
        for (int k = 1; k <= 2; ++k)
            if (ch == -1 || ch == k) {
                chan(k).output = on;
                chan(k).burst = chan(k).burst || chan(k).trig_source == "BUS";  // an INT-triggered channel waits for SOUR:TRIG:INT
                output_changed(chan(k));
            }
        return true;
    }
    return false;
}

bool Sim::redpitaya_acq(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
    constexpr std::size_t kBuf = 16384;
    int ch = -1;
    auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
    acquire_if_done();
    if (is("ACQ:RST")) {
        const auto k = dig_.kind;
        dig_ = Digitizer{};
        dig_.kind = k;
        dig_.trig = "DISABLED";
        return true;
    }
    if (is("ACQ:DEC:F") || is("ACQ:DEC")) {
        if (q) {
            r = std::to_string(dig_.dec);
            return true;
        }
        const double v = parse_number(a);
        const auto d = static_cast<long>(v);
        const bool factor = h.back().name == "F";
        if (v != std::floor(v) || d < 1 || d > 65536 || (!factor && (d & (d - 1)) != 0)) err(-224, "Illegal parameter value;decimation");
        dig_.dec = static_cast<int>(d);
        return true;
    }
    if (is("ACQ:DATA:UNIT")) {
        const auto u = upper(trim(a));
        if (u != "VOLTS" && u != "RAW") err(-224, "Illegal parameter value");
        dig_.rp_volts = u == "VOLTS";
        return true;
    }
    if (is("ACQ:DATA:FORM")) {
        const auto u = upper(trim(a));
        if (u != "ASCII" && u != "BIN") err(-224, "Illegal parameter value");
        dig_.rp_bin = u == "BIN";
        return true;
    }
    if (is("ACQ:TRIG:DLY")) {
        if (q) r = std::to_string(dig_.dly);
        else {
            const double v = parse_number(a);
            if (v != std::floor(v) || v < -8192 || v > 1e9) err(-222, "Data out of range");
            dig_.dly = static_cast<long>(v);
        }
        return true;
    }
    if (is("ACQ:START")) {
        dig_.rp_started = true;
        dig_.state = Digitizer::State::Stop;
        dig_.have = false;
        return true;
    }
    if (is("ACQ:STOP")) {
        dig_.rp_started = false;
        return true;
    }
    if (is("ACQ:TRIG:STAT") && q) {
        r = dig_.state == Digitizer::State::Wait ? "WAIT" : "TD";
        return true;
    }
    if (is("ACQ:TRIG:FILL") && q) {
        r = std::string(dig_.have ? "1" : "0");  // not the literal: GCC 12's -Wrestrict misfires on that assignment here
        return true;
    }
    if (is("ACQ:TRIG")) {
        const auto u = upper(trim(a));
        if (u != "NOW" && u != "AWG_PE" && u != "EXT_PE" && u != "DISABLED") err(-224, "Illegal parameter value;the emulator triggers on NOW, AWG_PE or EXT_PE");
        if (!dig_.rp_started) err(-221, "Settings conflict;ACQ:START first");
        dig_.trig = u;
        dig_.fs = 125e6 / dig_.dec;
        dig_.points = kBuf;
        dig_.pre = static_cast<std::size_t>(std::clamp<long>(static_cast<long>(kBuf / 2) - dig_.dly, 0, static_cast<long>(kBuf)));
        if (u != "DISABLED") arm(u == "NOW");
        return true;
    }
    if (is("ACQ:SOUR#:DATA") && q) {
        if (ch != 1 && ch != 2) err(-114, "Header suffix out of range");
        if (!dig_.have) err(-230, "Data corrupt or stale;no completed acquisition");
        const double qv = 2.0 / 16384;  // 14-bit ADC over +-1 V
        std::vector<double> v(kBuf);
        for (std::size_t m = 0; m < kBuf; ++m) v[m] = std::clamp(std::round(dig_.data[ch - 1][m] / qv) * qv, -1.0, 1.0 - qv);
        if (dig_.rp_bin) {
            std::string d;
            for (double x : v) {
                const float f = static_cast<float>(x);
                std::uint8_t b[4];
                std::memcpy(b, &f, 4);
                for (int i = 3; i >= 0; --i) d += static_cast<char>(b[i]);  // big-endian
            }
            r = scpi::encode_block(d);
        } else {
            std::string s = "{";
            char b[32];
            for (std::size_t m = 0; m < kBuf; ++m) {
                std::snprintf(b, sizeof b, "%s%.7f", m ? "," : "", v[m]);
                s += b;
            }
            r = s + "}";
        }
        return true;
    }
    return false;
}

}  // namespace fringe::dev::isim
