// The keys an encoder profile and a motion are read with, as data (signal_gen/base/key_table.hpp):
// encoder_from_json and motion_from_json read every key through these tables, and
// GET /api/v1/schema describes them from the same tables.
#pragma once

#include "signal_gen/base/key_table.hpp"

#include <string>
#include <vector>

namespace fringe {

// An encoder profile's keys (encoder.cpp), dotted inside the profile ("noise.sigma_add_v").
const KeyTable& encoder_keys();

// One kind of motion and its keys (motion.cpp); "kind" itself is not in the table.
struct MotionKindKeys {
    std::string kind, summary;
    KeyTable keys;
    bool editor = true;  // offered by the scenario editor (a table is kept as the scenario gives it)
};
const std::vector<MotionKindKeys>& motion_kinds();

}  // namespace fringe
