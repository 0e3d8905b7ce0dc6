// instrument-sim dialect: Siglent SDG2000X/SDG6000X (TrueArb) arbitrary waveform generators: WVDT uploads of raw bytes
// (WAVEDATA), ARWV, sample rate, burst on a manual trigger, phase-locked mode.
#include "drivers/sim/instrument_sim_core.hpp"

namespace fringe::dev::isim {

bool Sim::siglent(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
    int ch = -1;
    auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
    // key,value pairs (WAVEDATA's raw bytes taken whole)
    auto pairs = [&](std::string_view s) {
        std::map<std::string, std::string> kv;
        while (!s.empty()) {
            const auto c1 = s.find(',');
            if (c1 == std::string_view::npos) {
                kv[upper(trim(s))] = "";
                break;
            }
            const std::string key = upper(trim(s.substr(0, c1)));
            s.remove_prefix(c1 + 1);
            if (key == "WAVEDATA") {
                kv[key] = std::string(s);
                break;
            }
            const auto c2 = s.find(',');
            kv[key] = trim(s.substr(0, c2));
            s = c2 == std::string_view::npos ? std::string_view() : s.substr(c2 + 1);
        }
        return kv;
    };
    if (is("MODE")) {
        gen_.synced = upper(trim(a)) == "PHASE-LOCKED";
        return true;
    }
    if (is("C#:WVDT")) {
        auto& c = chan(ch);
        auto kv = pairs(a);
        if (!kv.count("WVNM") || !kv.count("WAVEDATA") || !kv.count("LENGTH")) err(-109, "Missing parameter");
        const std::string& d = kv["WAVEDATA"];
        if (std::to_string(d.size()) != kv["LENGTH"]) err(-160, "Block data error;WAVEDATA length differs from LENGTH");
        gen_.arbs[kv["WVNM"]] = codes_to_norm(d, 2, true, true, 32767);
        if (kv.count("AMPL")) c.vpp = parse_number(kv["AMPL"]);
        if (kv.count("OFST")) c.offset_v = parse_number(kv["OFST"]);
        check_levels(c);
        return true;
    }
    if (is("C#:ARWV")) {
        auto& c = chan(ch);
        auto kv = pairs(a);
        const auto it = gen_.arbs.find(kv["NAME"]);
        if (it == gen_.arbs.end()) err(-224, "Illegal parameter value;no such waveform");
        c.norm = it->second;
        c.start_s.reset();
        return true;
    }
    if (is("C#:SRAT")) {
        auto& c = chan(ch);
        if (q) {
            r = "C" + std::to_string(ch) + ":SRATE MODE,TARB,VALUE," + fmt(c.rate_hz);
            return true;
        }
        auto kv = pairs(a);
        if (kv["MODE"] != "TARB") err(-224, "Illegal parameter value;the emulator plays TrueArb (MODE,TARB)");
        const double v = parse_number(kv["VALUE"]);
        if (v < 1e-6 || v > gen_.max_rate) err(-222, "Data out of range");
        c.rate_hz = v;
        return true;
    }
    if (is("C#:BSWV")) {
        auto& c = chan(ch);
        auto kv = pairs(a);
        const double ov = c.vpp, oo = c.offset_v;
        if (kv.count("AMP")) c.vpp = parse_number(kv["AMP"]);
        if (kv.count("OFST")) c.offset_v = parse_number(kv["OFST"]);
        try {
            check_levels(c);
        } catch (...) {
            c.vpp = ov, c.offset_v = oo;
            throw;
        }
        return true;
    }
    if (is("C#:BTWV")) {
        auto& c = chan(ch);
        if (upper(trim(a)) == "MTRIG") {
            trigger({ch != 2 || gen_.synced, ch == 2 || gen_.synced}, false);
            return true;
        }
        auto kv = pairs(a);
        if (kv.count("STATE")) c.burst = kv["STATE"] == "ON";
        if (kv.count("TRSR")) c.trig_source = kv["TRSR"] == "MAN" ? "BUS" : kv["TRSR"];
        if (kv.count("TIME")) {
            if (kv["TIME"] == "INF") c.infinite = true;
            else if (parse_number(kv["TIME"]) == 1) c.infinite = false;
            else err(-222, "Data out of range;the emulator plays 1 or INF cycles");
        }
        return true;
    }
    if (is("C#:OUTP")) {
        auto& c = chan(ch);
        if (q) r = std::string("C") + std::to_string(ch) + ":OUTP " + (c.output ? "ON" : "OFF");
        else {
            c.output = parse_bool(split_commas(a).at(0));
            output_changed(c);
        }
        return true;
    }
    return false;
}

}  // namespace fringe::dev::isim
