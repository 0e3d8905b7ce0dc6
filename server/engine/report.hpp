// The run report (schema "fringe.report", version 3; docs/schema.md) as a struct. The engine
// (run.cpp, capture_run.cpp) fills one RunReport; to_json below is the one place it becomes
// JSON, for the store, the API and every rendering. Readers of stored reports (which may be
// older) read the JSON through the metric table (server/analysis/metrics.hpp).
//
// Typed here: the run's identity and times, status, verdict, the device, the sample counts,
// warnings, and each lane's entry with its error metrics. What an analyser finishes into its own
// JSON (spectrum, bounds, alignment, signal quality, traces, a registered analyser's results)
// is carried as that JSON: each has one to_json where it is computed.
#pragma once

#include "drivers/device.hpp"
#include "server/analysis/scoring.hpp"
#include "server/analysis/verdict.hpp"
#include "server/engine/preflight.hpp"
#include "server/engine/scenario.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace fringe {

// One diagnosis of a lane (report estimators[].diagnosis): a convention it broke, an
// efficiency that is not credible.
struct LaneDiagnosis {
    std::string code;
    std::string message;
};

// One lane of a run: an estimator under test, or the DUT's own position ("dut").
struct EstimatorReport {
    std::string label;
    std::string name;
    nlohmann::json params = nlohmann::json::object();
    nlohmann::json state;                  // the estimator's own state at the end (null: the DUT)
    ErrorMetrics metrics;
    int lines_per_rev = 0;                 // for the arcsec figures; 0: the encoder is unknown
    std::optional<nlohmann::json> abz;     // the DUT's ABZ readout (metrics.abz)
    std::optional<nlohmann::json> readout; // the DUT's own readout device (metrics.readout; device.dut)
    std::uint64_t convention_violations = 0;
    nlohmann::json spectrum;               // ErrorSpectrum::to_json
    nlohmann::json analysers = nlohmann::json::object();  // registered analysers' results by name
    nlohmann::json bounds;                 // bounds_json; null when they could not be computed
    std::vector<LaneDiagnosis> diagnosis;
};

struct RunReport {
    static constexpr const char* kSchema = "fringe.report";
    static constexpr int kSchemaVersion = 3;

    std::string id;
    std::string started_at, finished_at;   // ISO 8601 UTC
    double wall_s = 0;
    Scenario scenario;
    std::optional<dev::DeviceInfo> device;  // null until a device was opened
    std::optional<dev::DeviceInfo> device_output, device_input;  // separate generator and digitizer
    nlohmann::json provenance;              // provenance.hpp; null: omitted
    nlohmann::json alignment;               // the source's latency alignment; null without one
    nlohmann::json signal;                  // SignalQuality::to_json; null before the run started
    RunStatus status = RunStatus::Done;
    std::optional<Verdict> verdict;         // none: nothing could be scored (a capture without truth)
    std::string error;                      // empty: none
    std::vector<Finding> warnings;
    std::uint64_t samples_planned = 0, samples_processed = 0;
    std::vector<EstimatorReport> estimators;
    nlohmann::json measurements = nlohmann::json::array();  // evaluate_limits (limits.hpp)
    nlohmann::json traces = nlohmann::json::object();       // TraceRecorder::to_json
    nlohmann::json capture;                 // a capture run's own facts (capture_run.hpp); null: omitted
    // A scenario's "calibrate" (calibrated_run.hpp): the before pass, the correction, the
    // captures it was computed and verified on, and each lane before and after; null: omitted.
    nlohmann::json calibration;
};

// The report's "estimators" array (what the limits read, and to_json below).
nlohmann::json estimators_json(const std::vector<EstimatorReport>& lanes);
void to_json(nlohmann::json& j, const EstimatorReport& e);
// The whole report.
void to_json(nlohmann::json& j, const RunReport& r);

}  // namespace fringe
