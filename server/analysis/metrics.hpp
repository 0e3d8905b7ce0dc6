// The metric table: every figure a report carries, described once (name, unit, meaning, which
// lanes have it, whether a limit may name it, how its 95 % interval is computed, its summary
// column) together with where its value is read in a report. Limits, sweep tables, the CLI
// summary, the HTML and JUnit reports, the web tables, GET /schema and docs/schema.md all
// take their metrics from here: a new metric is one entry in metrics.cpp.
#pragma once

#include <nlohmann/json.hpp>

#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace fringe {

struct MetricInfo {
    std::string name, unit, description;
    bool run_level = false;    // a measurement of the run (alignment), not of an estimator lane
    std::string lanes;         // which lanes (or runs) have it
    bool limitable = true;     // a scenario limit may name it
    std::string uncertainty;   // how its 95 % interval is computed ("none: ..." when it has none)
    std::string column;        // heading in the summary tables (CLI, HTML, web, compare); "" = full table only
    std::string group = "error";  // "error", "bound", "evidence" (the CLI summary's lines) or "signal"
    // Its value from an estimator's report entry {"metrics", "bounds", ...} (run-level: from the
    // report, its "alignment" or "signal"); nullopt and why when it could not be measured.
    std::function<std::optional<double>(const nlohmann::json& entry, std::string* why)> value;
    // Its 95 % interval given the entry and the value; nullopt when it has none.
    std::function<std::optional<std::pair<double, double>>(const nlohmann::json& entry, double value)> interval;
};

// The fixed metrics, then harmonic_1x_rad .. harmonic_16x_rad (any order up to 64 is accepted).
const std::vector<MetricInfo>& metric_catalog();
std::optional<MetricInfo> find_metric(const std::string& name);  // nullopt if unknown
// The summary columns, in table order: of each estimator lane, or (run_level) of the run (the
// signal's quality).
std::vector<const MetricInfo*> summary_metrics(bool run_level = false);

// A metric's value from an estimator's report "metrics" and "bounds" (nullopt if it could not
// be measured; why in *why when given).
std::optional<double> metric_value(const std::string& name, const nlohmann::json& metrics, const nlohmann::json& bounds,
                                   std::string* why = nullptr);
// The same from a lane's whole report entry (estimators[i]: its metrics, bounds and
// analysers' results): what limits and sweeps use, so a metric an analyser writes is found.
std::optional<double> lane_metric_value(const std::string& name, const nlohmann::json& entry, std::string* why = nullptr);
std::optional<std::pair<double, double>> lane_metric_interval(const std::string& name, const nlohmann::json& entry, double value);
// A run-level metric's value from the run's facts: the report, or any object with its
// "alignment" and "signal" (nullopt and why when not measured).
std::optional<double> run_metric_value(const std::string& name, const nlohmann::json& run, std::string* why = nullptr);
// A metric's 95 % interval from the report's metrics "uncertainty" (value: the metric's value, for
// the same figure in other units); nullopt for metrics without one (extremes, counts, evidence).
std::optional<std::pair<double, double>> metric_interval(const std::string& name, const nlohmann::json& metrics, double value);

// One metric of one lane (or of the run) in a report: what every rendering shows.
struct MetricCell {
    const MetricInfo* info = nullptr;
    std::string lane;                           // estimator label, or "run"
    std::optional<double> value;
    std::optional<std::pair<double, double>> interval_95;
    std::string why;                            // why it was not measured
};
// Every metric of the table for each lane of a report (estimator metrics per lane, then the
// run-level ones once with lane "run"): rows in table order, lanes in report order.
std::vector<MetricCell> report_metrics(const nlohmann::json& report);

// report_metrics as JSON (GET /api/v1/runs/{id}/metrics, which the web's tables show):
// {"lanes": [labels..., "run"], "metrics": [{name, unit, description, lanes, scope, limitable,
// uncertainty, column?, "values": {lane: {"value" (null when not measured), "interval_95"?, "why"?}}}]}
nlohmann::json report_metrics_json(const nlohmann::json& report);

// The table as JSON (GET /schema "metrics") and as the markdown table in docs/schema.md.
nlohmann::json metric_table_json();
std::string metric_table_markdown();

}  // namespace fringe
