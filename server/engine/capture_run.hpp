// One estimator on a capture, through the run engine (the engine behind `fringe estimate` and
// POST /api/v1/captures/{id}/evaluate): the capture becomes a scenario whose device is
// capture:PATH, execute_run runs it like any run, and the report is the run's (schema
// "fringe.report") with the capture's own facts under "capture" (docs/schema.md).
#pragma once

#include "drivers/abz.hpp"
#include "drivers/capture_file.hpp"
#include "server/analysis/self_reference.hpp"
#include "server/engine/plan.hpp"
#include "server/engine/preflight.hpp"
#include "server/engine/report.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/encoder.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>

namespace fringe {

// The settle time of the scenario a capture was recorded with (its metadata's scenario.settle_s,
// `fringe run --record` and `fringe gen` write it); nothing when it does not say. What
// `fringe estimate` and `fringe calibrate` take when --settle-s is not given.
std::optional<double> recorded_settle_s(const nlohmann::json& meta);

struct CaptureRunOptions {
    std::string capture_path;
    std::string estimator;
    nlohmann::json params = nlohmann::json::object();
    // What the estimator is told about the encoder; default: the capture's sidecar/header.
    std::optional<EncoderProfile> encoder;
    double settle_s = 0.1;
    std::string estimates_path;  // optional CSV t,theta_rad,omega_rad_s,valid
    std::size_t block = 16384;
    std::function<void(std::uint64_t done)> progress;
    CaptureOptions capture;  // a sigrok session's channel map, the expanded-size cap
    // The DUT's ABZ readout (docs/abz.md): the capture driver decodes the capture's a/b/z lines
    // and the run scores them as the lane "dut" beside the estimator.
    std::optional<AbzConfig> abz;
    // The interface profile the signals are graded against (docs/signal-quality.md): its bands
    // are the capture run's measurements, with or without truth.
    std::optional<InterfaceProfile> interface;
    // Also measure the self-referenced error where the capture has truth (always without).
    bool self_reference = false;
};

// What one read of a capture finds: its length, rate, first time stamp, columns, metadata and
// the electrical radians travelled (distance, not net) in all and within settle_s of its start:
// the truth's, else the signals' own phase atan2(sin, cos) (a step below pi a sample), averaged
// over 16 samples and counted past a 0.5 rad deadband (a standing encoder's noise is no travel).
struct CaptureScan {
    std::uint64_t samples = 0;
    double sample_rate_hz = 0, t_first_s = 0;
    double travel_rad = 0, settle_travel_rad = 0;
    bool has_truth = false, has_abz = false;
    nlohmann::json meta;  // the sidecar's or header's metadata
};
CaptureScan scan_capture(const std::string& path, const CaptureOptions& options, double settle_s, std::size_t block = 65536);

// The motion a capture run's preflight checks (samples per cycle, a learner's settle travel) and
// its spectrum's segment length rest on: constant at the capture's mean electrical speed over
// the settle time, or over the whole capture without one (a capture's motion is the capture's,
// not what a scenario's "motion" says).
MotionProfile capture_motion(const CaptureScan& scan, double settle_s, int lines_per_rev);

// The self-referenced error's needs of the motion (docs/self-reference.md "What it cannot
// see"), checked on the capture: enough electrical cycles of travel after the settle time for
// a few windows, and not so slow that a window's samples run out before it spans the least
// cycles it is measured on. A warning, or nothing.
std::optional<Finding> self_reference_motion_check(const CaptureScan& scan, double settle_s);

// The run a capture is: its plan (plan_run of the scenario built from the capture), and what
// reading the capture once found (report "capture").
struct CapturePlan {
    RunPlan run;
    nlohmann::json facts;
    bool has_truth = false;
};

// Reads the capture once (its length, rate, first time stamp, and the truth's travel), builds
// the scenario (device capture:PATH, the one estimator, settle_s, no user limits) and plans it
// (plan_run: the estimator is built and checked here). Throws ConfigError / CaptureError
// (CaptureTooLarge) on bad input, before anything is written.
CapturePlan plan_capture_run(const CaptureRunOptions& o);

// plan_capture_run, then execute_run. The report's status is "error" (with "error") when the
// run failed part way (the estimates file is complete up to there); throws what
// plan_capture_run throws, and CaptureError when the estimates cannot be written.
RunReport run_capture(const CaptureRunOptions& o);

}  // namespace fringe
