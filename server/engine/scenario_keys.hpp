// The scenario's own scalar keys and a limit's keys, as data (signal_gen/base/key_table.hpp):
// scenario_from_json (scenario.cpp) reads them through these tables and GET /api/v1/schema
// describes them from the same tables. The structured keys are described by their own:
// encoder and motion in signal_gen/keys.hpp, estimators by the estimator registry, device
// by the driver registry.
#pragma once

#include "signal_gen/base/key_table.hpp"

namespace fringe {

const KeyTable& scenario_keys();
const KeyTable& limit_keys();

}  // namespace fringe
