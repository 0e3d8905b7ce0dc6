// Scenario: what to synthesise (encoder + motion + sampling + seed + duration). Later
// issues extend it with converter, device, estimators and limits. Strict JSON: unknown keys
// and out-of-range values are errors naming the key.
#pragma once

#include "server/engine/interface_profile.hpp"
#include "signal_gen/encoder.hpp"
#include "signal_gen/motion.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace fringe {

// An estimator under test in a run. label names it in reports and limits (default: name).
struct EstimatorSpec {
    std::string name, label;
    nlohmann::json params = nlohmann::json::object();
    std::optional<EncoderProfile> encoder;  // what it is told; default: the scenario's encoder
};

// A pass/fail limit on one metric (server/engine/limits.hpp lists the metrics). Outcome: FAIL
// beyond max/min; MARGINAL within marginal_fraction of the limit on the passing side.
struct Limit {
    std::string estimator = "*";  // a label, or "*" for every estimator
    std::string metric;
    std::optional<double> max, min;
    double marginal_fraction = 0.0;
};

// What a verdict needs besides limits (README "How a verdict is reached"): every estimator of a run is checked
// against these, and a run without this evidence FAILs instead of passing on nothing.
struct ScoringRules {
    int max_harmonic = 16;                  // error harmonics fitted: 1x..max_harmonic x
    std::uint64_t min_scored_samples = 1000;
    double min_scored_cycles = 3.0;         // electrical cycles of truth under the scored samples
    double min_valid_fraction = 0.95;       // valid share of the samples after the settle time
    std::uint64_t max_slipped_samples = 0;  // scored samples off by more than pi (cycle slips)
    bool self_reference = false;            // also measure each lane's error without truth (docs/self-reference.md)
};

// "Calibrate, apply, re-run" (docs/calibration.md "In one run"): after the run (the before
// pass), a correction for the lane named is computed from the before pass's signals and error
// record, applied to every lane that can take it, and the scenario runs again (the after pass)
// on another capture: another seed by default, or the motion or device the verify block says.
// A run's correction table is part of its report: at most this many entries (a chip's or a
// firmware's table holds 64-4096; `fringe calibrate --table-size` writes up to 2^20 to a file).
inline constexpr int kMaxRunTableSize = 4096;

struct CalibrateSpec {
    std::string lane;              // a label of an atan2 or pll2 lane
    std::size_t table_size = 64;   // N entries over an electrical period
    bool table_size_given = false;  // false: a board with a correction table takes its own count (plan_run)
    int harmonics = 16;            // K orders of the correction the table is built from
    bool lissajous = true;         // false: keep the lane's calibration, correct the angle only
    double min_cycles = 1;         // electrical cycles the error record needs for a correction (every angle seen)
    std::string error_source = "auto";  // "auto" (truth where the capture has it), "truth" or "self_reference"
    struct Verify {
        std::optional<std::uint64_t> seed;  // default: the scenario's seed + 1
        std::optional<MotionProfile> motion;  // default: the scenario's
        std::string device;        // default: the scenario's (a capture: device needs another capture here)
    } verify;
};

struct Scenario {
    std::string name = "unnamed";
    std::string description;
    EncoderProfile encoder;
    // false: the run has no encoder profile (a capture without one, `fringe estimate` without
    // --encoder); encoder is a stand-in: estimators are told none, errors have no arcsec, no bounds.
    bool encoder_known = true;
    MotionProfile motion;
    // Not a scenario key: plan_run replaced motion by the capture's own (capture_run.hpp
    // capture_motion) for a capture: device run, whatever the scenario said.
    bool motion_from_capture = false;
    // Not a scenario key: a capture: device's scenario left out sample_rate_hz or duration_s
    // (they are 0 until plan_run takes them from the capture).
    bool length_from_capture = false;
    // Not a scenario key: a capture: device's "motion" is not read (the run takes the capture's).
    bool motion_unread = false;
    double sample_rate_hz = 100000.0;
    double duration_s = 1.0;
    double t0_s = 0.0;
    std::uint64_t seed = 1;
    // Runs (ignored by `fringe gen`):
    std::string device = "loopback:";  // one device for output and input ("" when instruments is set)
    // Separate instruments (issue 14): "device": {"output": URI, "input": URI, "dut": URI}. The
    // same URI twice is one instrument (a generator with its own digitizer, or a loopback).
    struct Instruments {
        std::string output, input, dut;
    };
    std::optional<Instruments> instruments;
    // The interface profile the signals' quality is graded against (interface_profile.hpp);
    // none: not graded.
    std::optional<InterfaceProfile> interface;
    std::vector<EstimatorSpec> estimators;
    std::vector<Limit> limits;
    double settle_s = 0.1;
    std::string dut;  // DUT / board id (serial) for the history; default: the device's
    std::string dut_part;  // DUT part number (provenance); default: the bench's
    ScoringRules scoring;
    std::optional<CalibrateSpec> calibrate;  // none: one pass, as always

    std::uint64_t samples() const;
    // The device(s) in one line: the URI, or "OUTPUT -> INPUT" (run lists, history).
    std::string device_label() const;
    // Every URI the run opens, with the scenario field that names it ("device", "device.output", ...).
    std::vector<std::pair<std::string, std::string>> device_uris() const;
};

// base_dir resolves relative paths (an "encoder" given as a file name, a motion table).
Scenario scenario_from_json(const nlohmann::json& j, const std::string& base_dir);
Scenario load_scenario(const std::string& path);
EncoderProfile load_encoder(const std::string& path);
// An interface profile file (fixtures/interfaces/*.json); a fault names the file.
InterfaceProfile load_interface(const std::string& path);
nlohmann::json load_json_file(const std::string& path);  // throws ConfigError with the parse position
// A JSON value that is either inline or a file name (relative to base_dir): the object.
// file_out (optional) receives the resolved path, or "" when inline.
nlohmann::json resolve_json_ref(const nlohmann::json& j, const std::string& base_dir, std::string* file_out = nullptr);
void to_json(nlohmann::json& j, const Scenario& s);  // as run: the encoder inlined

}  // namespace fringe
