// The scenario's editable keys described as data (GET /api/v1/schema): the same
// self-description estimators and drivers give for their parameters (signal_gen/base/params.hpp),
// so the browser's scenario editor is built from it. Ranges and defaults mirror the readers
// (server/engine/scenario.cpp, signal_gen/encoder.cpp, signal_gen/motion.cpp); a test checks them
// against those readers.
#pragma once

#include <nlohmann/json.hpp>

namespace fringe {

// {"scenario":[params], "encoder":[params, dotted names], "motion":[{kind, summary, params}],
//  "limit":[params], "metrics":[{name, unit, description}]}
nlohmann::json scenario_schema();

}  // namespace fringe
