// "Calibrate, apply, re-run" in one run (a scenario's "calibrate"; docs/calibration.md "In one
// run"): execute_run comes here for such a scenario.
//
// 1. The before pass: the scenario as always (its signals recorded to a capture, or the capture
//    it replays).
// 2. A correction for the lane named, from that capture, through calibrate_capture
//    (calibrate.hpp: the same path as `fringe calibrate`): the Lissajous stage from the before
//    pass's signals, the periodic stage from atan2's truth-scored error (self-referenced without
//    truth). Written to RUN_ID.correction.json in RunOptions::calibration_dir.
// 3. Applied to every lane that can take it, one function per kind of lane (below): estimator
//    parameters, an external child's environment, a Modbus board's correction registers.
// 4. The after pass on another capture (another seed by default; the verify block's motion or
//    device), whose limits give the verdict. The report is the after pass's, with "calibration":
//    the before pass, the correction, both captures' identities and each lane side by side.
#pragma once

#include "server/engine/run.hpp"

#include <nlohmann/json.hpp>

#include <string>

namespace fringe {

// Never throws (as execute_run): a before pass that failed, a correction that could not be
// computed, an after pass that failed or was cancelled each end the report with its status and
// "calibration.status" saying which, and the before pass's figures kept.
RunReport execute_calibrated_run(RunPlan plan, const RunOptions& o);

// How a correction reaches a lane of the after pass: one function per kind of lane. Each returns
// what it did as {"kind", "applied", "how"} or {"kind", "applied": false, "why_not"}.
//
// An estimator in this process that takes correction=FILE (atan2, pll2): the parameter is set.
nlohmann::json apply_to_software_lane(EstimatorSpec& lane, const std::string& correction_path);
// An estimator run as a child process (`external`): its correction=FILE parameter where it
// declares one (the child is handed the file's path in its environment), else not yet.
nlohmann::json apply_to_external_lane(EstimatorSpec& lane, const std::string& correction_path);
// A Modbus board whose profile declares correction registers (the lane "dut", its own
// position): the correction written to them, read back and verified, correction_enable set
// (drivers/modbus_board.hpp write_correction); any other device: nothing to write.
nlohmann::json apply_to_board(const Scenario& after, const std::string& correction_path);
// The kind of a lane, and the function above for it; lanes of no kind are left as they are.
nlohmann::json apply_correction(EstimatorSpec& lane, const std::string& correction_path);

// A lane's figures for the side-by-side table (report "calibration.lanes[].before|after"): rms,
// largest error, mean, harmonics and the per-sample CRB, truth-scored where the pass had truth,
// else self-referenced ("error_source"); null figures when neither was measured.
nlohmann::json lane_figures(const nlohmann::json& lane);

}  // namespace fringe
