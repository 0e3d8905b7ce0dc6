// `fringe calibrate` (docs/calibration.md): a correction for atan2 from one capture, through
// the capture run (capture_run.hpp) so the error it rests on is the report's own figure.
//
// 1. Lissajous stage: the Heydemann ellipse fit over every sample of the capture.
// 2. atan2 with that stage runs on the capture (run_capture): its error against the angle is the
//    truth-scored one where the capture has theta_true (metrics.harmonics, metrics.mean), else the
//    self-referenced one (analysers.self_reference).
// 3. Periodic stage: that error record, inverted to the angle atan2 reads (calibration.hpp).
// 4. Offset: with truth, the error's mean; without, what keeps the corrected angle's mean where
//    atan2 with its told calibration had it (the Lissajous stage would move it).
#pragma once

#include "drivers/capture_file.hpp"
#include "estimator/correction.hpp"
#include "signal_gen/encoder.hpp"

#include <nlohmann/json.hpp>

#include <optional>
#include <string>

namespace fringe {

struct CalibrateOptions {
    std::string capture_path;
    std::string estimator = "atan2";  // the only one so far
    std::size_t table_size = 64;
    int harmonics = 16;
    bool lissajous = true;     // false: keep the estimator's nominal calibration, fit only the periodic stage
    std::optional<double> settle_s;  // none: the recording run's settle_s from the capture's metadata, else 0.1 s
    double min_cycles = 1;     // electrical cycles the error record needs: every angle seen (fewer: refused, no correction)
    std::string error_source = "auto";  // "auto": truth where the capture has it, else self-referenced; "truth"; "self_reference"
    std::optional<EncoderProfile> encoder;  // what atan2 is told (default: the capture's metadata)
    CaptureOptions capture;    // a capture: device URI's settings (channel map, size cap)
};

struct CalibrateResult {
    est::Correction correction;
    std::string source;          // "truth" or "self_reference"
    double before_rms_rad = 0;   // atan2 after the Lissajous stage, as the record measured it
    double periodic_rms_rad = 0;     // the record's periodic part (what the table corrects)
    double table_residual_rms_rad = 0;  // what the table leaves of it
    double noise_rms_rad = 0;    // what the record cannot attribute to the angle
    double predicted_rms_rad = 0;    // hypot(table residual, noise)
    double per_sample_crb_rad = 0;   // the report's bound, 0 when it has none
    double settle_s = 0;             // the settle time used, and where it came from
    std::string settle_from;         // "given", "capture" (the recording scenario's) or "default"
    nlohmann::json facts;        // all of the above and what they rest on, for the correction file's "calibrated_from"
};

// Throws ConfigError on bad options, std::runtime_error when the record is not usable (no truth
// and no self-referenced error, fewer than min_cycles under it, an ellipse fit rejected, a run
// that failed). `fringe calibrate` and a run's "calibrate" (calibrated_run.hpp) both come here.
CalibrateResult calibrate_capture(const CalibrateOptions& o);

}  // namespace fringe
