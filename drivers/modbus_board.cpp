#include "modbus_board.hpp"

#include "device.hpp"

#include "signal_gen/base/config.hpp"
#include "signal_gen/base/json_bounded.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace fringe::dev {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {
const std::vector<std::string> kRoles = {"sin_out", "cos_out", "sin_in", "cos_in", "position_count", "position_fraction",
                                         "position_rad", "status", "error_flags", "correction_table_rad", "correction_offset_rad",
                                         "trim_offset_sin_v", "trim_offset_cos_v", "trim_amplitude_sin_v", "trim_amplitude_cos_v", "trim_phase_rad",
                                         "correction_enable"};
// The correction roles (docs/modbus.md "Correction registers"): writable holding registers of a dut board.
const std::vector<std::string> kTrimRoles = {"trim_offset_sin_v", "trim_offset_cos_v", "trim_amplitude_sin_v", "trim_amplitude_cos_v", "trim_phase_rad"};
bool correction_role(const std::string& r) {
    return r == "correction_table_rad" || r == "correction_offset_rad" || r == "correction_enable" ||
           std::find(kTrimRoles.begin(), kTrimRoles.end(), r) != kTrimRoles.end();
}

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
        const bool corr = correction_role(role);
        if (role == "correction_table_rad") {
            if (!rr.has("count")) throw ConfigError(rr.path_of("count"), "a correction table needs its entry count (e.g. \"count\": 64)");
            if (!rr.has("scale")) throw ConfigError(rr.path_of("scale"), "a correction table needs its scale in rad per LSB (e.g. 9.587379924285257e-05, 2*pi/65536)");
            d.count = static_cast<int>(rr.integer("count", 2, 4096));
            if (d.type == RegType::U16 || d.type == RegType::U32)
                throw ConfigError(rr.path_of("type"), "a correction table holds signed corrections: s16, s32 or f32");
            if (d.address + d.count * d.words() > 65536) throw ConfigError(rr.path_of("count"), "the table runs past register 65535");
        } else if (rr.has("count")) {
            throw ConfigError(rr.path_of("count"), "only correction_table_rad takes a count");
        }
        if (corr && role != "correction_table_rad" && role != "correction_enable" && d.type != RegType::F32 && !rr.has("scale"))
            throw ConfigError(rr.path_of("scale"), std::string("an integer correction register needs its scale in ") +
                                                       (role == "correction_offset_rad" || role == "trim_phase_rad" ? "rad" : "V") + " per LSB");
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
        if (corr && (d.table != RegTable::Holding || !d.writable || !d.readable))
            throw ConfigError(rr.path_of(d.table != RegTable::Holding ? "table" : "access"), "a correction register is a holding register fringe writes and reads back (access rw)");
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
    // Correction registers: on a dut board, trims all or none, an offset or enable with something to apply, no overlaps.
    bool any_corr = false;
    for (const auto& [role, d] : b.regs) any_corr |= correction_role(role);
    if (any_corr) {
        const std::string rp = join_path(where, "registers");
        if (b.kind != "dut") throw ConfigError(rp, "correction registers belong to a dut board (kind \"dut\")");
        int trims = 0;
        for (const auto& t : kTrimRoles) trims += b.find(t) ? 1 : 0;
        if (trims != 0 && trims != static_cast<int>(kTrimRoles.size())) {
            std::string missing;
            for (const auto& t : kTrimRoles)
                if (!b.find(t)) missing += (missing.empty() ? "" : ", ") + t;
            throw ConfigError(rp, "Lissajous trims come all together: missing " + missing);
        }
        if (b.find("correction_offset_rad") && !b.find("correction_table_rad")) throw ConfigError(rp + ".correction_offset_rad", "needs a correction_table_rad");
        if (b.find("correction_enable") && !b.has_correction()) throw ConfigError(rp + ".correction_enable", "needs a correction_table_rad or the trims");
        for (const auto& [role, d] : b.regs) {
            if (!correction_role(role)) continue;
            const int a0 = d.address, a1 = d.address + d.count * d.words();
            for (const auto& [other, e] : b.regs) {
                if (other == role || e.table != RegTable::Holding) continue;
                const int b0 = e.address, b1 = e.address + e.count * e.words();
                if (a0 < b1 && b0 < a1) throw ConfigError(rp + "." + role, "overlaps " + other + " (registers " + std::to_string(b0) + ".." + std::to_string(b1 - 1) + ")");
            }
        }
    }
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

namespace {

std::string num17(double v) {
    char b[40];
    std::snprintf(b, sizeof b, "%.17g", v);
    return b;
}

const char* type_name(RegType t) {
    switch (t) {
        case RegType::U16: return "u16";
        case RegType::S16: return "s16";
        case RegType::U32: return "u32";
        case RegType::S32: return "s32";
        case RegType::F32: return "f32";
    }
    return "?";
}

// One value quantised to its register: an integer type's range is checked, never clamped.
RegisterValue quantise(const RegisterDef& r, const std::string& role, int index, int address, double value) {
    RegisterValue v;
    v.role = role;
    v.index = index;
    v.reg = r;
    v.address = address;
    v.value = value;
    const double raw = (value - r.offset) / r.scale;
    if (!std::isfinite(raw)) throw std::runtime_error(v.label() + " = " + num17(value) + " is not a finite register value");
    if (r.type == RegType::F32) {
        v.raw = static_cast<double>(static_cast<float>(raw));
    } else {
        const double lo = r.type == RegType::S16 ? -32768.0 : r.type == RegType::S32 ? -2147483648.0 : 0.0;
        const double hi = r.type == RegType::U16 ? 65535.0 : r.type == RegType::S16 ? 32767.0 : r.type == RegType::U32 ? 4294967295.0 : 2147483647.0;
        v.raw = std::nearbyint(raw);
        if (v.raw < lo || v.raw > hi)
            throw std::runtime_error(v.label() + " = " + num17(value) + (r.unit.empty() ? "" : " " + r.unit) + " needs raw " + num17(v.raw) + " at register " +
                                     std::to_string(address) + ", outside " + type_name(r.type) + " " + num17(lo) + ".." + num17(hi) + " at its scale " +
                                     num17(r.scale) + ": the correction does not fit the register (nothing written; a coarser scale in the profile, or a wider type)");
    }
    RegisterDef one = r;
    one.scale = 1.0;
    one.offset = 0.0;
    v.words = encode_register(one, v.raw);
    return v;
}

}  // namespace

std::vector<RegisterValue> plan_correction_writes(const BoardProfile& b, const est::Correction& c) {
    if (!b.has_correction())
        throw std::runtime_error("board " + b.name + " declares no correction registers (correction_table_rad, or the trim_* registers; docs/modbus.md \"Correction registers\")");
    std::vector<RegisterValue> out;
    const RegisterDef* table = b.find("correction_table_rad");
    const RegisterDef* offset = b.find("correction_offset_rad");
    const RegisterDef* enable = b.find("correction_enable");
    const bool trims = b.find("trim_offset_sin_v") != nullptr;
    if (!table && (!c.table.empty() || !c.cos_k.empty() || c.offset_rad != 0))
        throw std::runtime_error("board " + b.name + " has trims but no correction_table_rad: the correction's angle table and offset cannot be written (it takes a correction of the Lissajous stage only)");
    if (table && c.table.size() != static_cast<std::size_t>(table->count))
        throw std::runtime_error("the correction's table has " + std::to_string(c.table.size()) + " entries, board " + b.name + "'s correction_table_rad " +
                                 std::to_string(table->count) + ": compute it with that many (fringe calibrate --table-size " + std::to_string(table->count) +
                                 "); fringe does not resample a table");
    if (c.has_lissajous && !trims)
        throw std::runtime_error("the correction has a Lissajous stage (offsets, amplitudes, phase) but board " + b.name +
                                 " declares no trim registers: compute it without (fringe calibrate --no-lissajous)");
    if (enable) out.push_back(quantise(*enable, "correction_enable", -1, enable->address, 0));
    if (table) {
        const double fold = offset ? 0.0 : c.offset_rad;  // no offset register: the total subtracted in every entry
        for (int i = 0; i < table->count; ++i)
            out.push_back(quantise(*table, "correction_table_rad", i, table->address + i * table->words(), c.table[static_cast<std::size_t>(i)] + fold));
    }
    if (offset) out.push_back(quantise(*offset, "correction_offset_rad", -1, offset->address, c.offset_rad));
    if (trims) {
        // No Lissajous stage: the neutral trims (no offset, equal amplitudes, no phase error).
        const double vals[5] = {c.has_lissajous ? c.offset_sin_v : 0.0, c.has_lissajous ? c.offset_cos_v : 0.0, c.has_lissajous ? c.amplitude_sin_v : 1.0,
                                c.has_lissajous ? c.amplitude_cos_v : 1.0, c.has_lissajous ? c.quadrature_error_rad : 0.0};
        for (int k = 0; k < 5; ++k) {
            const std::string role = kTrimRoles[static_cast<std::size_t>(k)];
            const RegisterDef* r = b.find(role);
            out.push_back(quantise(*r, role, -1, r->address, vals[k]));
            // An amplitude that rounds to 0 (or below) at the register's scale: the board refuses
            // it after enable was cleared, and is left with no correction. Refused here, first.
            if ((k == 2 || k == 3) && !(out.back().raw * r->scale + r->offset > 0))
                throw std::runtime_error(out.back().label() + " = " + num17(vals[k]) + (r->unit.empty() ? "" : " " + r->unit) + " rounds to raw " +
                                         num17(out.back().raw) + " at register " + std::to_string(r->address) + " (scale " + num17(r->scale) +
                                         "): an amplitude must stay positive (nothing written)");
        }
    }
    if (enable) out.push_back(quantise(*enable, "correction_enable", -1, enable->address, 1));
    return out;
}

std::string modbus_writes_json(const BoardProfile& b, const std::vector<RegisterValue>& w) {
    json rows = json::array();
    for (const auto& v : w) {
        json words = json::array();
        for (auto x : v.words) words.push_back(x);
        rows.push_back({{"role", v.role}, {"index", v.index < 0 ? json() : json(v.index)}, {"address", v.address}, {"table", "holding"},
                        {"type", type_name(v.reg.type)}, {"word_order", v.reg.low_word_first ? "little" : "big"},
                        {"function", v.reg.write_function}, {"raw", v.raw}, {"words", words}, {"value", v.value}, {"unit", v.reg.unit}});
    }
    json j{{"schema", "fringe.modbus_writes"},
           {"schema_version", 1},
           {"board", b.name},
           {"order", "write in the order listed; correction_enable (if any) is cleared first and set last, so the board applies the whole correction at once"},
           {"addressing", "0-based register addresses (PDU); words are the 16-bit register values in address order"},
           {"writes", rows}};
    return j.dump(2) + "\n";
}

std::string modbus_writes_csv(const BoardProfile& b, const std::vector<RegisterValue>& w) {
    std::string out = "# fringe Modbus register writes for board " + b.name +
                      ": write in the order listed (correction_enable cleared first, set last); 0-based holding register addresses; "
                      "words are the 16-bit register values in address order\n"
                      "role,index,address,table,type,function,raw,words,value,unit\n";
    for (const auto& v : w) {
        std::string words;
        for (auto x : v.words) {
            if (!words.empty()) words.push_back(' ');
            words.append(std::to_string(x));
        }
        char row[160];
        std::snprintf(row, sizeof row, ",%s,%d,holding,%s,%d,%s,", v.index < 0 ? "" : std::to_string(v.index).c_str(), v.address, type_name(v.reg.type),
                      v.reg.write_function, num17(v.raw).c_str());
        out.append(v.role).append(row).append(words).append(",").append(num17(v.value)).append(",").append(v.reg.unit).append("\n");
    }
    return out;
}

std::vector<RegisterValue> write_correction(RegisterPort& port, const est::Correction& c) {
    const BoardProfile& b = port.board();
    std::vector<RegisterValue> plan = plan_correction_writes(b, c);  // throws before anything is written
    // Runs of consecutive table entries go in one request (at most 123 registers) where the
    // register is written with function 16; everything else one value per request.
    auto run_end = [&](std::size_t i) {
        std::size_t j = i + 1;
        if (plan[i].index < 0 || plan[i].reg.write_function != 16) return j;
        int regs = static_cast<int>(plan[i].words.size());
        while (j < plan.size() && plan[j].role == plan[i].role && plan[j].index == plan[j - 1].index + 1 &&
               regs + static_cast<int>(plan[j].words.size()) <= 123) {
            regs += static_cast<int>(plan[j].words.size());
            ++j;
        }
        return j;
    };
    auto what_of = [&](std::size_t i, std::size_t j, const char* verb) {
        std::size_t regs = 0;
        for (std::size_t k = i; k < j; ++k) regs += plan[k].words.size();
        std::string name = plan[i].index < 0 ? plan[i].role
                         : j - i == 1          ? plan[i].label()
                                               : plan[i].role + "[" + std::to_string(plan[i].index) + ".." + std::to_string(plan[j - 1].index) + "]";
        if (plan[i].role == "correction_enable") name += "=" + num17(plan[i].value);
        return std::string(verb) + " " + name + " @" + std::to_string(plan[i].address) + "+" + std::to_string(regs);
    };
    auto words_of = [&](std::size_t i, std::size_t j) {
        std::vector<std::uint16_t> w;
        for (std::size_t k = i; k < j; ++k) w.insert(w.end(), plan[k].words.begin(), plan[k].words.end());
        return w;
    };
    // Everything but the final enable, then read back and compare.
    const std::size_t last = plan.back().role == "correction_enable" ? plan.size() - 1 : plan.size();
    // Once correction_enable is cleared (the first write), a failure leaves the board without its
    // correction: the error says so (a user re-ran the write and found the board uncorrected).
    bool cleared = false;
    try {
    for (std::size_t i = 0; i < last;) {
        const std::size_t j = run_end(i);
        const auto w = words_of(i, j);
        port.write_words(plan[i].address, w, plan[i].reg.write_function, what_of(i, j, "write"));
        if (i == 0 && plan[0].role == "correction_enable") cleared = true;
        i = j;
    }
    auto verify = [&](std::size_t i, std::size_t j) {
        const auto want = words_of(i, j);
        std::vector<std::uint16_t> got(want.size());
        port.read_words(RegTable::Holding, plan[i].address, static_cast<int>(want.size()), got.data(), what_of(i, j, "read back"));
        std::size_t at = 0;
        for (std::size_t k = i; k < j; ++k) {
            const std::size_t n = plan[k].words.size();
            if (!std::equal(got.begin() + static_cast<long>(at), got.begin() + static_cast<long>(at + n), plan[k].words.begin())) {
                const double read = decode_register(plan[k].reg, got.data() + at);
                throw DeviceError("board " + b.name, plan[k].label() + " @" + std::to_string(plan[k].address) + " reads back " + num17(read) + " (" +
                                                         std::string(plan[k].reg.unit.empty() ? "" : plan[k].reg.unit + ", ") + "raw " +
                                                         num17(read / plan[k].reg.scale - plan[k].reg.offset / plan[k].reg.scale) + "), written " + num17(plan[k].raw) +
                                                         " raw: the board did not keep the value");
            }
            at += n;
        }
    };
    for (std::size_t i = 0; i < last;) {
        std::size_t j = i + 1;
        if (plan[i].index >= 0) {  // the table in reads of at most 125 registers, whatever its write function
            int regs = static_cast<int>(plan[i].words.size());
            while (j < last && plan[j].index == plan[j - 1].index + 1 && plan[j].role == plan[i].role && regs + static_cast<int>(plan[j].words.size()) <= 125) {
                regs += static_cast<int>(plan[j].words.size());
                ++j;
            }
        }
        verify(i, j);
        i = j;
    }
    if (last < plan.size()) {
        port.write_words(plan[last].address, plan[last].words, plan[last].reg.write_function, what_of(last, last + 1, "write"));
        std::uint16_t got = 0;
        port.read_words(RegTable::Holding, plan[last].address, 1, &got, what_of(last, last + 1, "read back"));
        if (got != plan[last].words[0])
            throw DeviceError("board " + b.name, "correction_enable @" + std::to_string(plan[last].address) + " reads back " + std::to_string(got) +
                                                     " after writing 1: the board refused the correction (the values read back as written)");
    }
    } catch (const Cancelled&) {
        throw;
    } catch (const DeviceError& e) {
        if (!cleared) throw;
        throw DeviceError(e.device(), std::string(e.what()).substr(e.device().size() + 2) +
                                          "; correction_enable was cleared first: the board applies no correction until a write succeeds");
    }
    return plan;
}

std::vector<RegisterValue> write_correction(const std::string& uri, const est::Correction& c) {
    auto dev = open(uri);
    RegisterPort* port = dev->registers();
    if (!port) throw DeviceError(uri, "not a Modbus board: a correction is written to a modbus+tcp or modbus+rtu board whose profile declares correction registers");
    return write_correction(*port, c);
}

std::optional<double> disable_correction(const std::string& uri) {
    auto dev = open(uri);
    RegisterPort* port = dev->registers();
    if (!port) throw DeviceError(uri, "not a Modbus board");
    const RegisterDef* e = port->board().find("correction_enable");
    if (!e) return std::nullopt;
    std::vector<std::uint16_t> was(static_cast<std::size_t>(e->words())), now(was.size());
    port->read_words(RegTable::Holding, e->address, e->words(), was.data(), "read correction_enable @" + std::to_string(e->address));
    const std::vector<std::uint16_t> zero = encode_register(*e, 0.0);
    port->write_words(e->address, zero, e->write_function, "write correction_enable=0 @" + std::to_string(e->address));
    port->read_words(RegTable::Holding, e->address, e->words(), now.data(), "read back correction_enable @" + std::to_string(e->address));
    if (now != zero) throw DeviceError(uri, "correction_enable read back " + std::to_string(decode_register(*e, now.data())) + " after writing 0");
    return decode_register(*e, was.data());
}

}  // namespace fringe::dev
