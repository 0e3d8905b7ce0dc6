// Sweeps (`fringe sweep SWEEP.json`): run a base scenario many times with parameters set by
// path (`encoder.noise.sigma_add_v`, `estimators[0].params.natural_freq_hz`, ...), either as
// explicit rows or as a cartesian grid, in parallel across cores, and tabulate chosen metrics
// (CSV and Markdown), optionally beside reference figures (the paper's, MODEL.md's).
#pragma once

#include <nlohmann/json.hpp>

#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace fringe {

struct SweepColumn {
    std::string estimator;  // label
    std::string metric;     // a metric_catalog() name
};

struct SweepRow {
    std::string label;
    nlohmann::json set = nlohmann::json::object();  // path -> value
    nlohmann::json reference = nlohmann::json::object();  // name -> figure (e.g. "paper", "model")
};

struct Sweep {
    std::string name, description;
    nlohmann::json base;  // scenario JSON with the encoder inlined
    std::string base_dir;
    std::vector<SweepColumn> columns;
    std::vector<SweepRow> rows;
    std::vector<std::string> reference_names;  // in column order
    int jobs = 0;  // 0: all cores
};

Sweep load_sweep(const std::string& path);
// Sets a value at a dotted path with [i] indices inside j; objects are created as needed.
void set_by_path(nlohmann::json& j, const std::string& path, const nlohmann::json& value);

struct SweepResult {
    SweepRow row;
    std::string verdict, status, error;
    std::vector<std::optional<double>> values;  // per column
    double wall_s = 0;
};

std::vector<SweepResult> run_sweep(const Sweep& s, int jobs, const std::function<void(std::size_t done, std::size_t total)>& progress = {});
std::string sweep_csv(const Sweep& s, const std::vector<SweepResult>& r);
std::string sweep_markdown(const Sweep& s, const std::vector<SweepResult>& r);

}  // namespace fringe
