// The run plan: a scenario checked once, in one place, into what the run engine executes.
// Every face of the engine makes one: `fringe run` (server/cli/cmd_run.cpp), POST runs and
// POST preflight (server/http/service.cpp, the run queue keeps the plan until a worker runs
// it), every sweep row (server/engine/sweep.cpp) and every capture evaluation
// (server/engine/capture_run.cpp). execute_run (run.hpp) checks nothing again; only what needs
// the opened device (its converter, preflight_device) is checked when the run opens it.
#pragma once

#include "estimator/estimator.hpp"
#include "server/engine/preflight.hpp"
#include "server/engine/scenario.hpp"

#include <cstddef>
#include <limits>
#include <memory>
#include <vector>

namespace fringe {

struct RunPlan {
    Scenario scenario;
    // One per scenario.estimators, built and reset with its parameters (which is how they are
    // checked) for the run to use: each estimator is constructed once per run. Null for one
    // that runs a child process (EstimatorTraits::child_process): it is started by the run.
    std::vector<std::unique_ptr<est::Estimator>> estimators;
    // What each estimator is (or, for a child process, will be) told: rate, encoder, params.
    std::vector<est::EstimatorConfig> configs;
    // The preflight's warnings (preflight.hpp); the run adds the opened device's own.
    std::vector<Finding> warnings;
    // The fewest samples any electrical cycle of the run gets (+inf for no motion).
    double samples_per_cycle = 0;
};

// How large a run a service takes (fringe serve --max-samples, --max-estimators,
// --max-limits); unbounded by default.
struct RunBudget {
    double max_samples = kInf;
    std::size_t max_estimators = std::numeric_limits<std::size_t>::max();
    std::size_t max_limits = std::numeric_limits<std::size_t>::max();
};

// A run beyond its budget (HTTP 413). code: too_many_samples, too_many_estimators or
// too_many_limits; field: duration_s, estimators or limits.
class RunTooLarge : public ConfigError {
public:
    RunTooLarge(std::string code, std::string field, const std::string& message) : ConfigError(std::move(field), message), code_(std::move(code)) {}
    const std::string& code() const { return code_; }

private:
    std::string code_;
};

// Checks a parsed scenario (scenario_from_json reads its keys and ranges) for running, in
// this order: its size against the budget (RunTooLarge, before anything is built), a "calibrate" block's lane, table size (a board's own) and after pass, estimators exist and accept their parameters (each is built here), limits name
// known metrics and estimators and can be measured, the device URIs' form and settings
// (nothing is opened), then the preflight's physics. Throws ConfigError naming the scenario
// key of the first error; returns the plan with the preflight's warnings.
RunPlan plan_run(Scenario sc, const RunBudget& budget = {});

}  // namespace fringe
