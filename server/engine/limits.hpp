// Metrics a limit can name, and the measurements of a run: each estimator's implicit evidence
// checks (docs/model.md "Evidence": scored samples, scored cycles, valid fraction) and the
// scenario's limits, with their outcomes and the verdict.
#pragma once

#include "server/engine/scenario.hpp"
#include "server/analysis/metrics.hpp"
#include "server/analysis/verdict.hpp"

#include <nlohmann/json.hpp>

#include <optional>
#include <utility>
#include <string>
#include <vector>

namespace fringe {

// The measurements of a finished run (report "measurements") from its "estimators" array.
// status: the run's; measurements of a run that did not complete are ERROR. verdict receives
// the worst outcome (PASS when there is none).
// run: the run's facts, {"alignment", "signal"} as in the report (null without them); run-level
// metrics read them, measured once with estimator "run".
// has_truth false (a capture without theta_true): the evidence checks are the self-referenced
// ones (docs/self-reference.md: self_ref_samples, self_ref_cycles, self_ref_valid_fraction
// against the scoring minimums), and a limit on a figure that needs truth is not measured.
nlohmann::json evaluate_limits(const Scenario& sc, const nlohmann::json& estimators, RunStatus status, Verdict& verdict,
                               const nlohmann::json& run = nullptr, bool has_truth = true);
}  // namespace fringe
