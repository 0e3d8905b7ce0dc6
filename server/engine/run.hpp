// The run engine: generate the encoder signals, play them through a device, capture, run the
// estimators under test, score against truth, apply limits, and build the report (report.hpp:
// a RunReport, schema "fringe.report" version 3 once serialised). Streams in blocks: memory does not grow with the run
// length (traces are decimated to a fixed number of points).
#pragma once

#include "server/engine/limits.hpp"
#include "server/engine/plan.hpp"
#include "server/engine/preflight.hpp"
#include "server/engine/report.hpp"
#include "server/engine/scenario.hpp"

#include <nlohmann/json.hpp>

#include <atomic>
#include <functional>
#include <memory>
#include <optional>
#include <string>

namespace fringe {

struct RunOptions {
    // Frames per pipeline step. 16384 keeps a step's frames and each lane's outputs (a few MB)
    // in the cores' caches and the run's memory at about 30 MB; 65536 took 20-30 % more CPU
    // time on perf-1e7-atan2.json (README "Measured performance"). Reports do not depend on it
    // beyond the last bits of sums taken per block.
    std::size_t block = 16384;
    std::size_t trace_points = 2000;
    std::function<void(std::uint64_t done, std::uint64_t total)> progress;
    const std::atomic<bool>* cancel = nullptr;
    std::string run_id;
    // Record the device input (with the aligned truth) to this capture (.csv or .fcap).
    std::string record_path;
    // Where the run came from (provenance.hpp): copied into report["provenance"]; its DUT
    // serial is filled from the device's board id when neither scenario nor bench set one.
    nlohmann::json provenance;
    // Threads for the pipeline (the source, the lanes and the traces side by side); 0: one per
    // hardware thread. The report does not depend on it.
    unsigned threads = 0;
    // Each block's output of the first estimator under test as it left the estimator (before
    // the samples without truth are dropped from scoring): `fringe estimate` writes its
    // estimates CSV from it. A throw ends the run with status "error".
    std::function<void(std::size_t n, const double* t_s, const double* theta_rad, const double* omega_rad_s, const std::uint8_t* valid)>
        estimates;
    // Filled when the run ends: seconds spent inside the first estimator (its throughput).
    double* estimator_s = nullptr;
    // A scenario's "calibrate": the folder the correction file (RUN_ID.correction.json) is
    // written to, and the before pass's capture while the correction is computed from it;
    // empty: a folder of its own under the system's temporary folder.
    std::string calibration_dir;
};

// Executes a run plan (plan.hpp: the scenario checked once, its estimators built). Never
// throws: device faults, sample loss, estimator failure, cancellation and any unexpected
// exception end the run with status "error" or "aborted" and a report of what was processed
// until then.
// The report converts to JSON (report.hpp to_json): `json j = execute_run(plan);`.
// A scenario with "calibrate" runs twice, before and after (calibrated_run.hpp), in one report.
RunReport execute_run(RunPlan plan, const RunOptions& o = {});
// One pass of the plan, whatever its "calibrate" says (the before and the after pass).
RunReport execute_pass(RunPlan plan, const RunOptions& o);
// plan_run, then the plan: throws plan_run's ConfigError.
RunReport execute_run(const Scenario& sc, const RunOptions& o = {});

// The report of a run that ended before it produced a sample (cancelled while queued, or the
// engine could not start): the same struct as execute_run's, so every rendering works.
RunReport unstarted_report(const Scenario& sc, const std::string& id, const std::string& started_at, RunStatus status, Verdict verdict,
                           const std::string& error, const nlohmann::json& provenance = nullptr);

// Exit code for a report: 0 PASS/MARGINAL, 1 FAIL, 2 ERROR/ABORTED.
int exit_code(const nlohmann::json& report);

// A UUIDv7 ("0193a4f2-6c1e-7b3d-9f00-1a2b3c4d5e6f"): unique across hosts, sorts by time.
std::string new_run_id();
std::string iso_now();  // "2026-11-21T15:07:45Z"

}  // namespace fringe
