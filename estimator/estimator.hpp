// The estimator interface (docs/estimators.md): an interpolation
// estimator under test turns sin/cos samples (V) into the unwrapped electrical phase
// theta_rad, the electrical rate omega_rad_s and a valid flag. Estimators are registered by
// name and describe their own parameters, so the CLI, HTTP API and web forms are built from
// one description.
//
// Lifecycle (liquid-dsp style): make -> reset(config) -> process(...) any number of times.
// process() does no I/O, no logging and no allocation per sample (the external adapter is
// the one exception: its samples go through a pipe).
#pragma once

#include "signal_gen/base/config.hpp"
#include "signal_gen/encoder.hpp"
#include "signal_gen/base/params.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace fringe::est {

// A run-time failure of an estimator (an external child that crashed, a filter whose
// covariance lost positive definiteness). Configuration problems throw ConfigError instead.
class EstimatorError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

using fringe::ParamInfo;
using fringe::ParamType;
using fringe::Params;
using fringe::parse_param_assignments;
using fringe::resolve_params;

struct EstimatorConfig {
    double sample_rate_hz = 0.0;
    // The encoder as the estimator is told it is (a profile file, or the capture's sidecar).
    // Estimators that need a model throw ConfigError when it is absent.
    std::optional<EncoderProfile> encoder;
    nlohmann::json params = nlohmann::json::object();
};

struct InputSpan {
    std::span<const double> sin_v, cos_v;
    std::size_t size() const { return sin_v.size(); }
};

struct OutputSpan {
    std::span<double> theta_rad;    // unwrapped electrical phase, a posteriori
    std::span<double> omega_rad_s;  // electrical rate
    std::span<std::uint8_t> valid;  // 0 while acquiring / calibrating
    std::size_t size() const { return theta_rad.size(); }
};

// How a scorer should grade the estimator (MODEL.md 6, "Efficiency").
enum class BoundClass { Memoryless, Tracker };
enum class Kinematics { CV, CA };

// The tracking prior an estimator declares: white acceleration (CV) or jerk (CA) whose PSD
// is tied to its natural frequency by q = wn^4*r*T (CV) or wn^6*r*T (CA), r being the
// per-sample phase variance of the signal (MODEL.md 4.3). The scorer evaluates the PCRB for
// this prior with r from the true signal model.
struct TrackingPrior {
    Kinematics kinematics = Kinematics::CV;
    double natural_freq_hz = 0.0;
};

class Estimator {
public:
    virtual ~Estimator() = default;
    virtual void reset(const EstimatorConfig& config) = 0;
    // in and out have equal sizes. Stream in blocks of any size: the result does not depend
    // on the partition.
    virtual void process(InputSpan in, OutputSpan out) = 0;
    // The end of the input: an estimator with pending output (a child process) checks that it
    // delivered exactly one estimate per input frame; throws EstimatorError if not.
    virtual void finish() {}
    virtual BoundClass bound_class() const { return BoundClass::Tracker; }
    virtual std::optional<TrackingPrior> prior() const { return std::nullopt; }
    // Diagnostics for the report (fitted calibration, final gain or kappa, ...).
    virtual nlohmann::json state() const { return nlohmann::json::object(); }
};

// What the engine asks about an estimator instead of comparing names (preflight, efficiency,
// the service's permission for child processes, the learning warning).
struct EstimatorTraits {
    // Its measurement model is an ideal sinusoid pair: on a signal with harmonics (a diffraction
    // encoder) its error is the model mismatch, not noise (preflight "model_mismatch").
    bool assumes_ideal_sinusoids = false;
    // Its measurement model takes the signals' amplitude from the encoder profile it is told (it
    // has no gain state that starts from the data): told another amplitude than the signals
    // have, it rejects them or lags (run warning "amplitude_mismatch").
    bool told_amplitude = false;
    // Learns the waveform shape from the signal over about this many electrical cycles of motion
    // (0: does not learn); told_param names the boolean parameter that gives it the shape instead.
    double learns_over_cycles = 0;
    std::string told_param;
    // Runs a command on this host: a service allows it only when started with --allow-external,
    // and its bound class and tracking prior are what its parameters declare (params.model,
    // params.natural_freq_hz), not what the object knows.
    bool child_process = false;
};

struct EstimatorInfo {
    std::string name;
    std::string summary;
    std::vector<ParamInfo> params;
    std::function<std::unique_ptr<Estimator>()> make;
    EstimatorTraits traits = {};
};
void to_json(nlohmann::json& j, const EstimatorInfo& e);

// All registered estimators, in a stable order: the built-in ones, then any registered.
const std::vector<EstimatorInfo>& registry();
// Adds an estimator (a name already taken is refused with std::invalid_argument). Register
// before any run starts: the registry is read without a lock. ScopedEstimator registers for
// the lifetime of an object (a test's estimator, a plug-in's).
void register_estimator(EstimatorInfo info);
void unregister_estimator(const std::string& name);
class ScopedEstimator {
public:
    explicit ScopedEstimator(EstimatorInfo info) : name_(info.name) { register_estimator(std::move(info)); }
    ~ScopedEstimator() { unregister_estimator(name_); }
    ScopedEstimator(const ScopedEstimator&) = delete;
    ScopedEstimator& operator=(const ScopedEstimator&) = delete;

private:
    std::string name_;
};
// Throws ConfigError("estimator", ...) listing the known names.
const EstimatorInfo& find(const std::string& name);
// The traits of a registered estimator; an unknown name has none set (it is refused elsewhere).
EstimatorTraits traits_of(const std::string& name);
// find + make + reset.
std::unique_ptr<Estimator> make(const std::string& name, const EstimatorConfig& config);

}  // namespace fringe::est
