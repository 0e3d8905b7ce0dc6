#include "server/engine/schema_info.hpp"

#include "server/engine/limits.hpp"
#include "server/engine/scenario_keys.hpp"
#include "signal_gen/base/params.hpp"
#include "signal_gen/keys.hpp"

namespace fringe {

using nlohmann::json;

json scenario_schema() {
    const json scenario = scenario_keys().keys();  // scenario.cpp reads with it
    // The encoder's and the motion's keys: the tables their readers read with (signal_gen/keys.hpp).
    const json encoder = encoder_keys().keys();
    json motion = json::array();
    for (const auto& k : motion_kinds()) {
        motion.push_back({{"kind", k.kind}, {"summary", k.summary}, {"params", k.keys.keys()}});
        if (!k.editor) motion.back()["editor"] = false;
    }
    const json limit = limit_keys().keys();
    return {{"scenario", scenario}, {"encoder", encoder}, {"motion", motion}, {"limit", limit}, {"metrics", metric_table_json()}};
}

}  // namespace fringe
