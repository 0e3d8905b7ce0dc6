// Modbus board profiles (fixtures/boards/*.json): the register map of an interface board,
// kept apart from the transport (libsigrok's protocol/api split). Shared by the modbus
// driver and the emulated board (board-sim). Each register has a role the driver knows:
//   sin_out, cos_out           DAC / drive values, volts (writable holding registers)
//   sin_in, cos_in             ADC readback, volts
//   position_count             DUT position, whole electrical periods (s32/u32)
//   position_fraction          DUT position, fraction of a period (u16 scaled 1/65536)
//   position_rad               DUT position in radians (alternative to count + fraction)
//   status, error_flags        DUT status words (error_flags != 0 marks the reading invalid)
//   correction_table_rad       DUT correction: `count` consecutive entries, rad (scale: rad per LSB; docs/modbus.md)
//   correction_offset_rad      DUT correction: the constant offset, rad
//   trim_offset_sin_v, trim_offset_cos_v, trim_amplitude_sin_v, trim_amplitude_cos_v, trim_phase_rad
//                              DUT Lissajous trims applied before its arctangent (V, V, rad)
//   correction_enable          DUT correction: 0 off; writing non-zero applies what the registers hold
// physical = raw * scale + offset; 32-bit types span two registers in word_order.
// Optional per register: the converter's bits over its range (raw units, e.g. volts at the
// pin), which gives fringe's bounds the quantisation step and makes a write outside the
// range an error, and the write function (16, or 6 one word per request). Per board: init
// writes at open (configuration registers) and checks read at open (identity, word order).
#pragma once

#include "estimator/correction.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace fringe::dev {

enum class RegTable { Holding, Input };
enum class RegType { U16, S16, U32, S32, F32 };

struct RegisterDef {
    std::string role;
    int address = 0;
    RegTable table = RegTable::Holding;
    RegType type = RegType::U16;
    bool low_word_first = false;  // word_order "little": the low 16 bits at the lower address
    double scale = 1.0, offset = 0.0;
    std::string unit;
    bool readable = true, writable = false;
    int write_function = 16;  // 16: write multiple registers; 6: write single register, one request per word
    int count = 1;            // correction_table_rad: entries, each words() registers, at consecutive addresses
    int bits = 0;             // converter resolution over [range_lo, range_hi] (0: not given)
    bool has_range = false;
    double range_lo = 0, range_hi = 0;  // raw units (what the register holds, e.g. volts at the pin)
    int words() const { return type == RegType::U16 || type == RegType::S16 ? 1 : 2; }
    double raw_of(double physical) const { return (physical - offset) / scale; }
    // Quantisation step in physical units: range / 2^bits when both are given, else the scale
    // of an integer register, else 0 (a float register with no stated resolution).
    double step() const;
    // The physical span around 0 that the range allows, symmetric (0: no range, or 0 outside it).
    double symmetric_range() const;
};

// A register written once at open (configuration) or read once at open and compared
// (identity, word order). Values are raw: no scale or offset.
struct RegisterWrite {
    RegisterDef reg;  // reg.role holds the entry's name
    double value = 0;
};
struct RegisterCheck {
    RegisterDef reg;
    double expect = 0, tolerance = 0;
    std::string hint;  // what a mismatch means, for the error
};

struct BoardProfile {
    std::string name, description, path;
    std::string kind;  // "analog-io" | "dut"
    std::map<std::string, RegisterDef> regs;
    double settle_s = 0.001;  // after a write, before reading back
    int average = 1;          // readings averaged per step
    std::vector<RegisterCheck> checks;  // read at open, before the init writes
    std::vector<RegisterWrite> init;    // written at open, in order
    const RegisterDef* find(const std::string& role) const {
        auto it = regs.find(role);
        return it == regs.end() ? nullptr : &it->second;
    }
    // The correction registers (docs/modbus.md "Correction registers"): a table, trims, or both.
    bool has_correction() const { return find("correction_table_rad") || find("trim_offset_sin_v"); }
    bool has_dut_position() const { return find("position_rad") || (find("position_count") && find("position_fraction")); }
};

// By name (fixtures/boards/NAME.json, or $FRINGE_BOARDS/NAME.json) or by path. Strict:
// unknown keys and bad values throw ConfigError naming the key.
BoardProfile load_board(const std::string& name_or_path);
BoardProfile board_from_json(const nlohmann::json& j, const std::string& where);
std::string boards_dir();
std::vector<std::string> board_names();

// Physical value -> register words (rounded, clamped to the type's range).
std::vector<std::uint16_t> encode_register(const RegisterDef& r, double value);
// Register words -> physical value.
double decode_register(const RegisterDef& r, const std::uint16_t* words);
// The same words decoded with the other word order (for "the words are swapped" errors).
double decode_swapped(const RegisterDef& r, const std::uint16_t* words);

// Contiguous read batches: registers of one table merged while the span stays <= max_regs
// (Modbus allows at most 125 registers per read).
struct ReadBatch {
    RegTable table;
    int address = 0, count = 0;
    std::vector<const RegisterDef*> regs;
};
std::vector<ReadBatch> plan_reads(const std::vector<const RegisterDef*>& regs, int max_regs = 125);

// The register writes that put a correction (estimator/correction.hpp) on a board whose profile
// declares correction registers, in the order they are written: correction_enable = 0 (when
// declared), the table entries, the offset, the trims, correction_enable = 1. Each value is
// quantised to its register (raw = round((value - offset) / scale) for integer types); a value
// that does not fit the type is an error naming the entry, and nothing is planned. Without a
// correction_offset_rad register the offset is folded into every table entry (the total subtracted).
// A correction whose table has another entry count than the board's, or a Lissajous stage for a
// board without trims, is refused (std::runtime_error saying what to do).
struct RegisterValue {
    std::string role;  // "correction_table_rad", "correction_offset_rad", "trim_phase_rad", "correction_enable"
    int index = -1;    // table entry, else -1
    RegisterDef reg;   // its register (a copy: the plan outlives the device)
    int address = 0;   // this value's first register
    double value = 0;  // physical (rad, V, or the enable flag)
    double raw = 0;    // what the register holds (an integer for integer types)
    std::vector<std::uint16_t> words;
    std::string label() const { return index < 0 ? role : role + "[" + std::to_string(index) + "]"; }
};
std::vector<RegisterValue> plan_correction_writes(const BoardProfile& b, const est::Correction& c);
// The same as a file a user without fringe can load on the bench: JSON (schema
// "fringe.modbus_writes") or, for a path ending in .csv, CSV with one line per value.
std::string modbus_writes_json(const BoardProfile& b, const std::vector<RegisterValue>& w);
std::string modbus_writes_csv(const BoardProfile& b, const std::vector<RegisterValue>& w);

class RegisterPort;
// Writes the planned values to the board (the table in requests of at most 123 registers, or
// one per word where the register's write_function is 6), reads every one back and compares the
// words, then writes correction_enable = 1 and reads it back (a board that refuses the correction
// clears it). Throws DeviceError naming the register on a failed request or a readback that
// differs; the plan is checked before anything is written. Returns the plan.
std::vector<RegisterValue> write_correction(RegisterPort& port, const est::Correction& c);
// Opens the board at uri (a modbus+tcp or modbus+rtu URI: its checks and init writes run first,
// and it is locked against runs) and writes the correction to it.
std::vector<RegisterValue> write_correction(const std::string& uri, const est::Correction& c);
// Opens the board at uri and clears its correction_enable (read back): the board then applies no
// correction. Returns the value it held, or nothing when the profile declares no correction_enable.
std::optional<double> disable_correction(const std::string& uri);

}  // namespace fringe::dev
