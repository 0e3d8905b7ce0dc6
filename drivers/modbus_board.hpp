// Modbus board profiles (fixtures/boards/*.json): the register map of an interface board,
// kept apart from the transport (libsigrok's protocol/api split). Shared by the modbus
// driver and the emulated board (board-sim). Each register has a role the driver knows:
//   sin_out, cos_out           DAC / drive values, volts (writable holding registers)
//   sin_in, cos_in             ADC readback, volts
//   position_count             DUT position, whole electrical periods (s32/u32)
//   position_fraction          DUT position, fraction of a period (u16 scaled 1/65536)
//   position_rad               DUT position in radians (alternative to count + fraction)
//   status, error_flags        DUT status words (error_flags != 0 marks the reading invalid)
// physical = raw * scale + offset; 32-bit types span two registers in word_order.
#pragma once

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
    int words() const { return type == RegType::U16 || type == RegType::S16 ? 1 : 2; }
};

struct BoardProfile {
    std::string name, description, path;
    std::string kind;  // "analog-io" | "dut"
    std::map<std::string, RegisterDef> regs;
    double settle_s = 0.001;  // after a write, before reading back
    int average = 1;          // readings averaged per step
    const RegisterDef* find(const std::string& role) const {
        auto it = regs.find(role);
        return it == regs.end() ? nullptr : &it->second;
    }
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

// Contiguous read batches: registers of one table merged while the span stays <= max_regs
// (Modbus allows at most 125 registers per read).
struct ReadBatch {
    RegTable table;
    int address = 0, count = 0;
    std::vector<const RegisterDef*> regs;
};
std::vector<ReadBatch> plan_reads(const std::vector<const RegisterDef*>& regs, int max_regs = 125);

}  // namespace fringe::dev
