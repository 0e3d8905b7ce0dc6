// instrument-sim dialect: Rigol DG800/DG900/DG1000Z arbitrary waveform generators: DAC16 point packets (CON/END),
// APPLy:ARBitrary, burst on a bus trigger, phase sync.
#include "drivers/sim/instrument_sim_core.hpp"

namespace fringe::dev::isim {

bool Sim::rigol(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
    int ch = -1;
    auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
    if (is("[SOUR#]:APPL:ARB") || is("[SOUR#]:FUNC:ARB:SRAT")) {
        auto& c = chan(ch);
        if (q) r = fmt(c.rate_hz);
        else {
            const double v = parse_number(split_commas(a).at(0));
            if (v < 1e-6 || v > gen_.max_rate) err(-222, "Data out of range");
            c.rate_hz = v;
        }
        return true;
    }
    if (is("[SOUR#]:TRAC:DATA:DAC16")) {
        const int k = ch == -1 ? 0 : ch - 1;
        chan(ch);
        const auto parts = a.find(',');
        const auto parts2 = parts == std::string::npos ? std::string::npos : a.find(',', parts + 1);
        if (parts2 == std::string::npos || upper(trim(a.substr(0, parts))) != "VOLATILE") err(-109, "Missing parameter");
        const std::string flag = upper(trim(a.substr(parts + 1, parts2 - parts - 1)));
        if (flag != "CON" && flag != "END") err(-224, "Illegal parameter value");
        const std::string d = block_arg(a.substr(parts2 + 1));
        if (d.size() % 2 || d.size() > 32768) err(-222, "Data out of range;a packet holds at most 16384 points");
        auto& pend = gen_.rigol_pending[k];
        const double full = gen_.dac_bits == 14 ? 16383.0 : 65535.0;
        for (std::size_t i = 0; i < d.size(); i += 2) {
            const auto u = static_cast<std::uint16_t>(static_cast<std::uint8_t>(d[i]) | (static_cast<std::uint8_t>(d[i + 1]) << 8));
            if (u > full) err(-222, "Data out of range;DAC code " + std::to_string(u));
            pend.push_back(u);
        }
        if (pend.size() > gen_.memory) {
            pend.clear();
            err(-225, "Out of memory");
        }
        if (flag == "END") {
            auto& c = gen_.ch[static_cast<std::size_t>(k)];
            c.norm.resize(pend.size());
            for (std::size_t i = 0; i < pend.size(); ++i) c.norm[i] = static_cast<double>(pend[i]) / full * 2 - 1;
            pend.clear();
            c.start_s.reset();
        }
        return true;
    }
    if (is("[SOUR#]:VOLT:OFFS") || is("[SOUR#]:VOLT")) {
        auto& c = chan(ch);
        const bool offs = h.back().name == "OFFS";
        double& field = offs ? c.offset_v : c.vpp;
        if (q) r = fmt(field);
        else {
            const double old = field;
            field = parse_number(a);
            try {
                check_levels(c);
            } catch (...) {
                field = old;
                throw;
            }
        }
        return true;
    }
    if (is("[SOUR#]:BURS:STAT") || is("[SOUR#]:BURS")) {
        chan(ch).burst = parse_bool(a);
        return true;
    }
    if (is("[SOUR#]:BURS:MODE")) {
        const auto u = upper(trim(a));
        if (u != "TRIG" && u != "TRIGGERED" && u != "INF" && u != "INFINITY" && u != "GAT" && u != "GATED") err(-224, "Illegal parameter value");
        chan(ch).infinite = u.rfind("INF", 0) == 0;
        return true;
    }
    if (is("[SOUR#]:BURS:NCYC")) {
        auto& c = chan(ch);
        if (parse_number(a) != 1) err(-222, "Data out of range;the emulator plays 1 cycle or INF mode");
        (void)c;
        return true;
    }
    if (is("[SOUR#]:BURS:TRIG:SOUR")) {
        auto& c = chan(ch);
        const auto u = upper(trim(a));
        c.trig_source = u.rfind("MAN", 0) == 0 ? "BUS" : u;
        return true;
    }
    if (is("[SOUR#]:BURS:TRIG") || is("[SOUR#]:BURS:TRIG:IMM")) {
        std::array<bool, 2> w{ch != 2, ch == 2};
        trigger(w, false);
        return true;
    }
    if (is("[SOUR#]:PHAS:SYNC")) {
        gen_.synced = true;
        return true;
    }
    if (is("OUTP#") || is("OUTP#:STAT")) {
        auto& c = chan(ch);
        if (q) r = c.output ? "ON" : "OFF";
        else {
            c.output = parse_bool(a);
            output_changed(c);
        }
        return true;
    }
    return false;
}

}  // namespace fringe::dev::isim
