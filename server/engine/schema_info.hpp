// The scenario's keys described as data (GET /api/v1/schema): the same self-description
// estimators and drivers give for their parameters (signal_gen/base/params.hpp), so the
// browser's scenario editor is built from it. The encoder's and the motion's keys are the
// tables their readers read with (signal_gen/keys.hpp: every key they read is described there,
// tested); the scenario's own keys mirror server/engine/scenario.cpp, which a test checks.
#pragma once

#include <nlohmann/json.hpp>

namespace fringe {

// {"scenario":[params], "encoder":[params, dotted names; "editor": false for the keys the
//  editor does not offer], "motion":[{kind, summary, params}],
//  "limit":[params], "metrics":[{name, unit, description}]}
nlohmann::json scenario_schema();

}  // namespace fringe
