// Metrics a limit can name, and the measurements of a run: each estimator's implicit evidence
// checks (docs/model.md "Evidence": scored samples, scored cycles, valid fraction) and the
// scenario's limits, with their outcomes and the verdict.
#pragma once

#include "server/engine/scenario.hpp"
#include "server/analysis/verdict.hpp"

#include <nlohmann/json.hpp>

#include <optional>
#include <utility>
#include <string>
#include <vector>

namespace fringe {

struct MetricInfo {
    std::string name, unit, description;
    bool run_level = false;  // a measurement of the run (alignment), not of an estimator
};
// The fixed metrics, then harmonic_1x_rad .. harmonic_16x_rad (any order up to 64 is accepted).
const std::vector<MetricInfo>& metric_catalog();
std::optional<MetricInfo> find_metric(const std::string& name);  // nullopt if unknown
// A metric's value from an estimator's report "metrics" and "bounds" (nullopt if it could not
// be measured; why in *why when given).
std::optional<double> metric_value(const std::string& name, const nlohmann::json& metrics, const nlohmann::json& bounds,
                                   std::string* why = nullptr);

// A metric's 95 % interval from the report's metrics "uncertainty" (value: the metric's value, for
// the same figure in other units); nullopt for metrics without one (extremes, counts, evidence).
std::optional<std::pair<double, double>> metric_interval(const std::string& name, const nlohmann::json& metrics, double value);

// The measurements of a finished run (report "measurements") from its "estimators" array.
// status: the run's; measurements of a run that did not complete are ERROR. verdict receives
// the worst outcome (PASS when there is none).
// alignment: the report's "alignment" (null without one); run-level metrics read it, measured
// once with estimator "run".
nlohmann::json evaluate_limits(const Scenario& sc, const nlohmann::json& estimators, RunStatus status, Verdict& verdict,
                               const nlohmann::json& alignment = nullptr);
// A run-level metric's value from the report's "alignment" (nullopt and why when not measured).
std::optional<double> run_metric_value(const std::string& name, const nlohmann::json& alignment, std::string* why = nullptr);

}  // namespace fringe
