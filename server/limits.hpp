// Metrics a limit can name, and the measurements of a run: each estimator's implicit evidence
// checks (DESIGN.md "Trust": scored samples, scored cycles, valid fraction) and the
// scenario's limits, with their outcomes and the verdict.
#pragma once

#include "scenario.hpp"
#include "verdict.hpp"

#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

namespace fringe {

struct MetricInfo {
    std::string name, unit, description;
};
// The fixed metrics, then harmonic_1x_rad .. harmonic_16x_rad (any order up to 64 is accepted).
const std::vector<MetricInfo>& metric_catalog();
std::optional<MetricInfo> find_metric(const std::string& name);  // nullopt if unknown
// A metric's value from an estimator's report "metrics" and "bounds" (nullopt if it could not
// be measured; why in *why when given).
std::optional<double> metric_value(const std::string& name, const nlohmann::json& metrics, const nlohmann::json& bounds,
                                   std::string* why = nullptr);

// The measurements of a finished run (report "measurements") from its "estimators" array.
// status: the run's; measurements of a run that did not complete are ERROR. verdict receives
// the worst outcome (PASS when there is none).
nlohmann::json evaluate_limits(const Scenario& sc, const nlohmann::json& estimators, RunStatus status, Verdict& verdict);

}  // namespace fringe
