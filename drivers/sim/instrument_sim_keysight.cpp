// instrument-sim dialect: Keysight/Agilent 33500B and 33600A arbitrary waveform generators: arbitrary waveforms as DAC
// codes (DATA:ARB:DAC), sample rate, amplitude and offset, channel sync, burst on a bus trigger.
#include "drivers/sim/instrument_sim_core.hpp"

namespace fringe::dev::isim {

bool Sim::keysight(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
    int ch = -1;
    auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
    if (is("FORM:BORD")) {
        if (q) r = gen_.little_endian ? "SWAP" : "NORM";
        else {
            const auto u = upper(trim(a));
            if (u != "NORM" && u != "NORMAL" && u != "SWAP" && u != "SWAPPED") err(-224, "Illegal parameter value");
            gen_.little_endian = u.rfind("SWAP", 0) == 0;
        }
        return true;
    }
    if (is("[SOUR#]:DATA:VOL:CLE")) {
        gen_.arbs.clear();
        return true;
    }
    if (is("[SOUR#]:DATA:ARB:DAC") || is("[SOUR#]:DATA:ARB")) {
        const bool dac = h.back().name == "DAC";
        chan(ch);
        const auto comma = a.find(',');
        if (comma == std::string::npos) err(-109, "Missing parameter");
        const std::string name = upper(trim(a.substr(0, comma)));
        const std::string rest = ltrim(a.substr(comma + 1));
        std::vector<double> v;
        if (dac) {
            v = codes_to_norm(block_arg(rest), 2, gen_.little_endian, true, 32767);
        } else if (!rest.empty() && rest[0] == '#') {  // float32 block
            const std::string d = block_arg(rest);
            if (d.size() % 4) err(-160, "Block data error");
            for (std::size_t k = 0; k < d.size(); k += 4) {
                std::uint8_t b[4];
                for (int i = 0; i < 4; ++i) b[i] = static_cast<std::uint8_t>(d[k + static_cast<std::size_t>(gen_.little_endian ? i : 3 - i)]);
                float f;
                std::memcpy(&f, b, 4);
                if (!(f >= -1.0001f && f <= 1.0001f)) err(-222, "Data out of range");
                v.push_back(std::clamp(static_cast<double>(f), -1.0, 1.0));
            }
        } else {
            for (const auto& x : split_commas(rest)) {
                const double f = parse_number(x);
                if (f < -1 || f > 1) err(-222, "Data out of range");
                v.push_back(f);
            }
        }
        if (v.size() < 8) err(-222, "Data out of range;at least 8 points");
        if (v.size() > gen_.memory) err(-225, "Out of memory");
        gen_.arbs[name] = std::move(v);
        return true;
    }
    if (is("[SOUR#]:DATA:ATTR:POIN") && q) {
        const auto it = gen_.arbs.find(upper(trim(a)));
        if (it == gen_.arbs.end()) err(-224, "Illegal parameter value;no such arb");
        r = std::to_string(it->second.size());
        return true;
    }
    if (is("[SOUR#]:DATA:ATTR:AVER") && q) {
        const auto it = gen_.arbs.find(upper(trim(a)));
        if (it == gen_.arbs.end()) err(-224, "Illegal parameter value;no such arb");
        double s = 0;
        for (double x : it->second) s += x;
        r = fmt(s / static_cast<double>(it->second.size()));
        return true;
    }
    if (is("[SOUR#]:FUNC:ARB:SRAT")) {
        auto& c = chan(ch);
        if (q) r = fmt(c.rate_hz);
        else {
            const double v = parse_number(a);
            if (v < 1e-6 || v > gen_.max_rate) err(-222, "Data out of range");
            c.rate_hz = v;
        }
        return true;
    }
    if (is("[SOUR#]:FUNC:ARB:SYNC")) {
        gen_.synced = true;
        return true;
    }
    if (is("[SOUR#]:FUNC:ARB")) {
        auto& c = chan(ch);
        const auto it = gen_.arbs.find(upper(trim(a)));
        if (it == gen_.arbs.end()) err(-224, "Illegal parameter value;no such arb waveform");
        c.norm = it->second;
        c.start_s.reset();
        return true;
    }
    if (is("[SOUR#]:FUNC")) {
        chan(ch);
        if (q) r = "ARB";
        return true;
    }
    if (is("[SOUR#]:VOLT:OFFS")) {
        auto& c = chan(ch);
        if (q) r = fmt(c.offset_v);
        else {
            const double old = c.offset_v;
            c.offset_v = parse_number(a);
            try {
                check_levels(c);
            } catch (...) {
                c.offset_v = old;
                throw;
            }
        }
        return true;
    }
    if (is("[SOUR#]:VOLT")) {
        auto& c = chan(ch);
        if (q) r = fmt(c.vpp);
        else {
            const double old = c.vpp, v = parse_number(a);
            if (v < 1e-3) err(-222, "Data out of range");
            c.vpp = v;
            try {
                check_levels(c);
            } catch (...) {
                c.vpp = old;
                throw;
            }
        }
        return true;
    }
    if (is("[SOUR#]:BURS:MODE")) {
        chan(ch);
        return true;
    }
    if (is("[SOUR#]:BURS:NCYC")) {
        auto& c = chan(ch);
        const auto u = upper(trim(a));
        if (u == "INF" || u == "INFINITY") c.infinite = true;
        else {
            const double n = parse_number(a);
            if (n != 1) err(-222, "Data out of range;the emulator plays 1 or INF cycles");
            c.infinite = false;
        }
        return true;
    }
    if (is("[SOUR#]:BURS:STAT")) {
        chan(ch).burst = parse_bool(a);
        return true;
    }
    if (is("TRIG#:SOUR")) {
        auto& c = chan(ch);
        c.trig_source = upper(trim(a));
        return true;
    }
    if (is("OUTP#")) {
        auto& c = chan(ch);
        if (q) r = c.output ? "1" : "0";
        else {
            c.output = parse_bool(a);
            output_changed(c);
        }
        return true;
    }
    if (is("ABOR")) return true;
    return false;
}

}  // namespace fringe::dev::isim
