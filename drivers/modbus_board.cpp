#include "modbus_board.hpp"

#include "signal_gen/base/config.hpp"
#include "signal_gen/base/json_bounded.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace fringe::dev {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {
const std::vector<std::string> kRoles = {"sin_out", "cos_out", "sin_in", "cos_in", "position_count", "position_fraction",
                                         "position_rad", "status", "error_flags"};

RegType type_of(const std::string& s) {
    if (s == "u16") return RegType::U16;
    if (s == "s16") return RegType::S16;
    if (s == "u32") return RegType::U32;
    if (s == "s32") return RegType::S32;
    return RegType::F32;
}
}  // namespace

std::string boards_dir() {
    if (const char* d = std::getenv("FRINGE_BOARDS"); d && *d) return d;
    return FRINGE_SOURCE_DIR "/fixtures/boards";
}

std::vector<std::string> board_names() {
    std::vector<std::string> out;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(boards_dir(), ec))
        if (e.path().extension() == ".json") out.push_back(e.path().stem().string());
    std::sort(out.begin(), out.end());
    return out;
}

namespace {

std::string join_path(const std::string& where, const std::string& key) { return where.empty() ? key : where + "." + key; }

// Modbus function for writes: 16 (write multiple registers) or 6 (write single register).
int read_write_function(JsonReader& rr, int def) {
    const auto fc = static_cast<int>(rr.integer("write_function", def, 1, 127));
    if (fc != 6 && fc != 16) throw ConfigError(rr.path_of("write_function"), "must be 16 (write multiple registers) or 6 (write single register)");
    return fc;
}

// Address, table, type, word order and write function: what every register entry has.
void read_location(JsonReader& rr, RegisterDef& d, const std::string& order, int board_fc) {
    d.address = static_cast<int>(rr.integer("address", 0, 65535));
    d.table = rr.choice("table", "holding", {"holding", "input"}) == "holding" ? RegTable::Holding : RegTable::Input;
    d.type = type_of(rr.choice("type", "u16", {"u16", "s16", "u32", "s32", "f32"}));
    d.low_word_first = rr.choice("word_order", order, {"big", "little"}) == "little";
    d.write_function = read_write_function(rr, board_fc);
    if (d.address + d.words() > 65536) throw ConfigError(rr.path_of("address"), "register runs past 65535");
}

// "range": [lo, hi] in raw units.
void read_range(JsonReader& rr, RegisterDef& d) {
    if (!rr.has("range")) return;
    const auto& v = rr.raw("range");
    if (!v.is_array() || v.size() != 2 || !v[0].is_number() || !v[1].is_number() || !(v[0].get<double>() < v[1].get<double>()))
        throw ConfigError(rr.path_of("range"), "expected [low, high] in register units with low < high");
    d.has_range = true;
    d.range_lo = v[0].get<double>();
    d.range_hi = v[1].get<double>();
}

// "checks" / "init": arrays of register entries with a name.
template <class F>
void each_entry(JsonReader& r, const std::string& key, const std::string& where, F&& f) {
    if (!r.has(key)) return;
    const auto& arr = r.raw(key);
    if (!arr.is_array()) throw ConfigError(join_path(where, key), "expected an array of registers");
    for (std::size_t i = 0; i < arr.size(); ++i) {
        const std::string path = join_path(where, key) + "[" + std::to_string(i) + "]";
        if (!arr[i].is_object()) throw ConfigError(path, "expected an object");
        JsonReader er(arr[i], path);
        f(er);
        er.finish();
    }
}

}  // namespace

double RegisterDef::step() const {
    if (bits > 0 && has_range) return (range_hi - range_lo) / std::ldexp(1.0, bits) * std::fabs(scale);
    return type == RegType::F32 ? 0.0 : std::fabs(scale);
}

double RegisterDef::symmetric_range() const {
    if (!has_range) return 0.0;
    double a = range_lo * scale + offset, b = range_hi * scale + offset;
    if (a > b) std::swap(a, b);
    return a < 0 && b > 0 ? std::min(-a, b) : 0.0;
}

BoardProfile board_from_json(const json& j, const std::string& where) {
    JsonReader r(j, where);
    BoardProfile b;
    b.name = r.string("name");
    b.description = r.string("description", "");
    b.kind = r.choice("kind", "analog-io", {"analog-io", "dut"});
    const std::string order = r.choice("word_order", "big", {"big", "little"});
    const int board_fc = read_write_function(r, 16);
    b.settle_s = r.number("settle_s", 0.001, 0.0, 60.0);
    b.average = static_cast<int>(r.integer("average", 1, 1, 1000));
    if (!j.contains("registers") || !j["registers"].is_object()) throw ConfigError(join_path(where, "registers"), "expected an object of role -> register");
    const json& regs = r.raw("registers");
    for (const auto& [role, rj] : regs.items()) {
        const std::string path = join_path(where, "registers." + role);
        if (std::find(kRoles.begin(), kRoles.end(), role) == kRoles.end()) {
            std::string known;
            for (const auto& k : kRoles) known += (known.empty() ? "" : ", ") + k;
            throw ConfigError(path, "unknown register role (known: " + known + ")");
        }
        JsonReader rr(rj, path);
        RegisterDef d;
        d.role = role;
        read_location(rr, d, order, board_fc);
        d.scale = rr.number("scale", 1.0, -1e12, 1e12);
        if (d.scale == 0) throw ConfigError(rr.path_of("scale"), "must not be 0");
        d.offset = rr.number("offset", 0.0, -1e12, 1e12);
        d.unit = rr.string("unit", "");
        d.bits = static_cast<int>(rr.integer("bits", 0, 0, 32));
        read_range(rr, d);
        if (d.bits > 0 && !d.has_range) throw ConfigError(rr.path_of("bits"), "needs a 'range' ([low, high] in register units) that the bits divide");
        const std::string access = rr.choice("access", d.table == RegTable::Input ? "r" : "rw", {"r", "w", "rw"});
        d.readable = access != "w";
        d.writable = access != "r";
        if (d.writable && d.table == RegTable::Input) throw ConfigError(rr.path_of("access"), "input registers are read-only");
        rr.finish();
        b.regs[role] = d;
    }
    each_entry(r, "checks", where, [&](JsonReader& er) {
        RegisterCheck c;
        c.reg.role = er.string("name");
        read_location(er, c.reg, order, board_fc);
        c.expect = er.number("expect", -1e300, 1e300);
        c.tolerance = er.number("tolerance", 0.0, 0.0, 1e300);
        c.hint = er.string("hint", "");
        b.checks.push_back(c);
    });
    each_entry(r, "init", where, [&](JsonReader& er) {
        RegisterWrite w;
        w.reg.role = er.string("name");
        read_location(er, w.reg, order, board_fc);
        if (w.reg.table == RegTable::Input) throw ConfigError(er.path_of("table"), "input registers are read-only");
        w.value = er.number("value", -1e300, 1e300);
        if (w.reg.type != RegType::F32) {  // an integer the type holds exactly, not a rounded or clamped one
            const double lo = w.reg.type == RegType::S16 ? -32768.0 : w.reg.type == RegType::S32 ? -2147483648.0 : 0.0;
            const double hi = w.reg.type == RegType::U16 ? 65535.0 : w.reg.type == RegType::S16 ? 32767.0 : w.reg.type == RegType::U32 ? 4294967295.0 : 2147483647.0;
            if (w.value != std::floor(w.value) || w.value < lo || w.value > hi)
                throw ConfigError(er.path_of("value"), "must be an integer in " + std::to_string(static_cast<long long>(lo)) + ".." +
                                                           std::to_string(static_cast<long long>(hi)) + " for its type");
        }
        w.reg.writable = true;
        b.init.push_back(w);
    });
    r.finish();
    for (const char* need : {"sin_out", "cos_out"}) {
        const auto* d = b.find(need);
        if (!d) throw ConfigError(join_path(where, "registers"), std::string("a board needs a writable '") + need + "' register");
        if (!d->writable) throw ConfigError(join_path(where, std::string("registers.") + need + ".access"), "must be writable");
    }
    if (b.kind == "dut" && !b.has_dut_position())
        throw ConfigError(join_path(where, "registers"), "a dut board needs position_count + position_fraction, or position_rad");
    if (b.kind == "analog-io" && (!b.find("sin_in") || !b.find("cos_in")))
        throw ConfigError(join_path(where, "registers"), "an analog-io board needs sin_in and cos_in");
    return b;
}

BoardProfile load_board(const std::string& name_or_path) {
    fs::path p(name_or_path);
    if (name_or_path.find('/') == std::string::npos && p.extension() != ".json") p = fs::path(boards_dir()) / (name_or_path + ".json");
    std::ifstream f(p);
    if (!f) {
        std::string known;
        for (const auto& n : board_names()) known += (known.empty() ? "" : ", ") + n;
        throw ConfigError("device.board", "no board profile '" + name_or_path + "' (" + p.string() + "; known: " + known + ")");
    }
    json j;
    try {
        std::ostringstream text;
        text << f.rdbuf();
        j = parse_json_bounded(text.str(), p.string());
    } catch (const ConfigError& e) {
        throw ConfigError("device.board", e.what());
    }
    BoardProfile b;
    try {
        b = board_from_json(j, "");
    } catch (const ConfigError& e) {
        throw ConfigError("device.board", p.string() + ": " + e.what());
    }
    b.path = p.string();
    return b;
}

std::vector<std::uint16_t> encode_register(const RegisterDef& r, double value) {
    const double raw = (value - r.offset) / r.scale;
    std::uint32_t bits = 0;
    auto clamp_round = [&](double lo, double hi) { return std::clamp(std::nearbyint(std::isfinite(raw) ? raw : 0.0), lo, hi); };
    switch (r.type) {
        case RegType::U16: return {static_cast<std::uint16_t>(clamp_round(0, 65535))};
        case RegType::S16: return {static_cast<std::uint16_t>(static_cast<std::int16_t>(clamp_round(-32768, 32767)))};
        case RegType::U32: bits = static_cast<std::uint32_t>(clamp_round(0, 4294967295.0)); break;
        case RegType::S32: bits = static_cast<std::uint32_t>(static_cast<std::int32_t>(clamp_round(-2147483648.0, 2147483647.0))); break;
        case RegType::F32: {
            const float f = static_cast<float>(raw);
            std::memcpy(&bits, &f, 4);
            break;
        }
    }
    const auto hi = static_cast<std::uint16_t>(bits >> 16), lo = static_cast<std::uint16_t>(bits & 0xffff);
    return r.low_word_first ? std::vector<std::uint16_t>{lo, hi} : std::vector<std::uint16_t>{hi, lo};
}

double decode_swapped(const RegisterDef& r, const std::uint16_t* w) {
    RegisterDef o = r;
    o.low_word_first = !r.low_word_first;
    return decode_register(o, w);
}

double decode_register(const RegisterDef& r, const std::uint16_t* w) {
    double raw = 0;
    if (r.words() == 1) {
        raw = r.type == RegType::S16 ? static_cast<double>(static_cast<std::int16_t>(w[0])) : static_cast<double>(w[0]);
    } else {
        const std::uint32_t bits = r.low_word_first ? (static_cast<std::uint32_t>(w[1]) << 16 | w[0]) : (static_cast<std::uint32_t>(w[0]) << 16 | w[1]);
        if (r.type == RegType::U32) raw = static_cast<double>(bits);
        else if (r.type == RegType::S32) raw = static_cast<double>(static_cast<std::int32_t>(bits));
        else {
            float f;
            std::memcpy(&f, &bits, 4);
            raw = static_cast<double>(f);
        }
    }
    return raw * r.scale + r.offset;
}

std::vector<ReadBatch> plan_reads(const std::vector<const RegisterDef*>& regs, int max_regs) {
    std::vector<ReadBatch> out;
    for (RegTable t : {RegTable::Holding, RegTable::Input}) {
        std::vector<const RegisterDef*> v;
        for (const auto* r : regs)
            if (r && r->table == t) v.push_back(r);
        std::sort(v.begin(), v.end(), [](const RegisterDef* a, const RegisterDef* b) { return a->address < b->address; });
        for (const auto* r : v) {
            const int end = r->address + r->words();
            if (!out.empty() && out.back().table == t && end - out.back().address <= max_regs) {
                out.back().count = std::max(out.back().count, end - out.back().address);
                out.back().regs.push_back(r);
            } else {
                out.push_back({t, r->address, r->words(), {r}});
            }
        }
    }
    return out;
}

}  // namespace fringe::dev
