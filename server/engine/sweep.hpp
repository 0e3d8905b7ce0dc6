// Sweeps (`fringe sweep SWEEP.json`): run a base scenario many times with parameters set by
// path (`encoder.noise.sigma_add_v`, `estimators[0].params.natural_freq_hz`, ...), either as
// explicit rows or as a cartesian grid, in parallel across cores, and tabulate chosen metrics
// (CSV and Markdown), optionally beside reference figures (the paper's, MODEL.md's).
#pragma once

#include "server/engine/plan.hpp"

#include <nlohmann/json.hpp>

#include <cstddef>
#include <functional>
#include <memory>
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
    // Each row's plan, made when load_sweep checked the row, for the row's first run to execute
    // (so its estimators are built once); taken by that run, after which a row is planned again.
    // Shared by copies of the sweep.
    std::shared_ptr<std::vector<std::unique_ptr<RunPlan>>> plans;
};

Sweep load_sweep(const std::string& path);
// Sets a value at a dotted path with [i] indices inside j; objects are created as needed.
void set_by_path(nlohmann::json& j, const std::string& path, const nlohmann::json& value);

struct SweepResult {
    SweepRow row;
    std::string verdict, status, error;
    std::vector<std::optional<double>> values;  // per column
    std::vector<std::optional<std::pair<double, double>>> intervals;  // per column: its 95 % interval, where the metric has one
    double wall_s = 0;
};

// Runs one row's plan (plan_run of its scenario) and returns its report (default:
// execute_run). fringe sweep --store gives each run its deterministic id and provenance and
// stores it.
using SweepExecute = std::function<nlohmann::json(std::size_t row, RunPlan plan)>;
// rows: which rows, in this order (null: all); the results come back in that order.
std::vector<SweepResult> run_sweep(const Sweep& s, int jobs, const std::function<void(std::size_t done, std::size_t total)>& progress = {},
                                   const std::vector<std::size_t>* rows = nullptr, const SweepExecute& execute = {});
// What a row's table cells are, from its run's report (a stored one, for --collect).
SweepResult sweep_result(const Sweep& s, const SweepRow& row, const nlohmann::json& report);

// SHA-256 of what decides the runs (the base scenario, every row's settings and the fringe
// version, PROJECT_VERSION in CMakeLists.txt), hex. The version: this fringe's, or `version`.
std::string sweep_digest(const Sweep& s);
std::string sweep_digest(const Sweep& s, const std::string& version);
// Row k's run id: "sweep-" + 16 hex digits of the digest + "-" + k (4 digits or more). The
// same sweep file and fringe version give the same ids on every host, so a retried shard finds
// its rows stored; another version (an upgrade) gives other ids, so rows are never mixed.
std::string sweep_run_id(const Sweep& s, std::size_t k);

// --shard I/N: I in [0, N). Parses "I/N"; throws ConfigError("shard", ...).
struct Shard {
    std::size_t index = 0, count = 1;
};
Shard parse_shard(const std::string& text);
// The batch scheduler's: SLURM_ARRAY_TASK_ID (less SLURM_ARRAY_TASK_MIN) of
// SLURM_ARRAY_TASK_COUNT, or Kubernetes' JOB_COMPLETION_INDEX of count_hint (or
// $FRINGE_SHARD_COUNT). nullopt when none is set.
std::optional<Shard> shard_from_env(std::size_t count_hint = 0);
std::string sweep_csv(const Sweep& s, const std::vector<SweepResult>& r);
std::string sweep_markdown(const Sweep& s, const std::vector<SweepResult>& r);

}  // namespace fringe
