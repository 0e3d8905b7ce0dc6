// instrument-sim dialect: a generic SCPI scope or digitizer: sample rate and points, the
// trigger (EXT: the generator's sync output, or immediate) and its position (pretrigger),
// RUN/SINGle/STOP, and the :WAV readout (source, BYTE or WORD, start/stop, preamble).
#include "drivers/sim/instrument_sim_core.hpp"

namespace fringe::dev::isim {

bool Sim::scope(const std::vector<Node>& h, bool q, const std::string& a, std::optional<std::string>& r) {
    int ch = -1;
    auto is = [&](const char* pat) { return match_from(h, 0, parse_pattern(pat), 0, &ch); };
    acquire_if_done();
    if (is("STOP") || is("RUN")) {
        if (h[0].name == "STOP" && dig_.state != Digitizer::State::Stop) dig_.state = Digitizer::State::Stop;
        return true;
    }
    if (is("SING")) {
        if (dig_.points < 1 || dig_.pre > dig_.points) err(-221, "Settings conflict;trigger position beyond the record");
        arm(dig_.trig == "IMM");
        return true;
    }
    if (is("ACQ:SRAT")) {
        if (q) r = fmt(dig_.fs);
        else {
            const double v = parse_number(a);
            if (v < 1 || v > 10e9) err(-222, "Data out of range");
            dig_.fs = v;
        }
        return true;
    }
    if (is("ACQ:POIN")) {
        if (q) r = std::to_string(dig_.points);
        else {
            const double v = parse_number(a);
            if (v < 1 || v > 50e6 || v != std::floor(v)) err(-222, "Data out of range;1..50000000 points");
            dig_.points = static_cast<std::size_t>(v);
        }
        return true;
    }
    if (is("TRIG:SOUR")) {
        const auto u = upper(trim(a));
        if (q) r = dig_.trig;
        else if (u == "EXT" || u == "EXTERNAL") dig_.trig = "EXT";
        else if (u == "IMM" || u == "IMMEDIATE") dig_.trig = "IMM";
        else err(-224, "Illegal parameter value");
        return true;
    }
    if (is("TRIG:POS")) {
        if (q) r = std::to_string(dig_.pre);
        else {
            const double v = parse_number(a);
            if (v < 0 || v != std::floor(v) || v > 50e6) err(-222, "Data out of range");
            dig_.pre = static_cast<std::size_t>(v);
        }
        return true;
    }
    if (is("TRIG:STAT") && q) {
        r = dig_.state == Digitizer::State::Wait ? "WAIT" : dig_.state == Digitizer::State::Run ? "RUN" : "STOP";
        return true;
    }
    if (is("WAV:SOUR")) {
        const auto u = upper(trim(a));
        if (q) r = "CHAN" + std::to_string(dig_.wav_source);
        else if (u == "CHAN1" || u == "CHANNEL1") dig_.wav_source = 1;
        else if (u == "CHAN2" || u == "CHANNEL2") dig_.wav_source = 2;
        else err(-224, "Illegal parameter value");
        return true;
    }
    if (is("WAV:FORM")) {
        const auto u = upper(trim(a));
        if (q) r = dig_.wav_format;
        else if (u == "BYTE" || u == "WORD") dig_.wav_format = u;
        else err(-224, "Illegal parameter value");
        return true;
    }
    if (is("WAV:BYT")) {
        const auto u = upper(trim(a));
        if (q) r = dig_.wav_lsb ? "LSBF" : "MSBF";
        else if (u == "LSBF" || u == "MSBF") dig_.wav_lsb = u == "LSBF";
        else err(-224, "Illegal parameter value");
        return true;
    }
    if (is("WAV:MODE")) return true;
    if (is("WAV:STAR") || is("WAV:STOP")) {
        const bool start = h.back().name == "STAR";
        if (q) {
            r = std::to_string(start ? dig_.wav_start : (dig_.wav_stop ? dig_.wav_stop : dig_.points));
            return true;
        }
        const double v = parse_number(a);
        if (v < 1 || v != std::floor(v) || v > static_cast<double>(dig_.points)) err(-222, "Data out of range");
        (start ? dig_.wav_start : dig_.wav_stop) = static_cast<std::size_t>(v);
        return true;
    }
    const bool word = dig_.wav_format == "WORD";
    const double yinc = 2 * o_.digitizer_range_v / (word ? 65536.0 : 256.0), yref = word ? 32768 : 128;
    if (is("WAV:PRE") && q) {
        r = std::to_string(word ? 1 : 0) + ",2," + std::to_string(dig_.points) + ",1," + fmt(1 / dig_.fs) + "," +
            fmt(-static_cast<double>(dig_.pre) / dig_.fs) + ",0," + fmt(yinc) + ",0," + fmt(yref);
        return true;
    }
    if (is("WAV:DATA") && q) {
        if (!dig_.have) err(-230, "Data corrupt or stale;no completed acquisition");
        const std::size_t lo = dig_.wav_start, hi = dig_.wav_stop ? dig_.wav_stop : dig_.points;
        if (lo > hi) err(-221, "Settings conflict;:WAV:STAR after :WAV:STOP");
        std::string d;
        d.reserve((hi - lo + 1) * (word ? 2 : 1));
        const double full = word ? 65535 : 255;
        for (std::size_t m = lo - 1; m < hi; ++m) {
            const double code = std::clamp(std::round(dig_.data[dig_.wav_source - 1][m] / yinc) + yref, 0.0, full);
            const auto u = static_cast<std::uint16_t>(code);
            if (word) {
                d += static_cast<char>(dig_.wav_lsb ? (u & 0xFF) : (u >> 8));
                d += static_cast<char>(dig_.wav_lsb ? (u >> 8) : (u & 0xFF));
            } else {
                d += static_cast<char>(u);
            }
        }
        r = scpi::encode_block(d);
        return true;
    }
    return false;
}

}  // namespace fringe::dev::isim
