// Preflight: a scenario checked against physics before a run or sweep row starts
// (README "How a verdict is reached"). Errors stop the run (exit 2, HTTP 400) naming the field and the cause;
// warnings travel in the report, the CLI output, JUnit properties and the HTML and web pages.
#pragma once

#include "server/engine/scenario.hpp"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace fringe {

namespace dev {
struct DeviceInfo;
struct UriParts;
}  // namespace dev

struct Finding {
    bool error = false;
    std::string code;     // "undersampled", "double_quantisation", ...
    std::string field;    // the scenario key it is about
    std::string message;  // what and why, with the numbers
};

// Peak |v| of an encoder's noise-free channels over one electrical cycle (V), with its
// Lissajous offsets and gains: the amplitude an estimator told this profile expects.
double peak_signal_v(const EncoderProfile& enc);

// After the run: each lane whose estimator takes the amplitude from its profile
// (traits.told_amplitude) told a peak more than 25 % off the signals' measured peak (the
// signal-quality figures: half of max - min of the fitted shape): warning "amplitude_mismatch".
std::vector<Finding> amplitude_findings(const Scenario& sc, const nlohmann::json& signal);

void to_json(nlohmann::json& j, const Finding& f);

// Peak electrical rate over the run, as samples per electrical cycle at that rate (the
// smallest number of samples any cycle of the run gets). +inf for a motion that never moves.
double min_samples_per_cycle(const Scenario& sc);

// Checks that need only the scenario (the physics: sampling, settle time, learning, model
// mismatch, quantisation, clipping) and the input device URI's settings, from plan_run
// (plan.hpp), which passes min_samples_per_cycle and the checked URI. Throws ConfigError for
// the first error; returns the warnings.
std::vector<Finding> preflight(const Scenario& sc, double samples_per_cycle, const dev::UriParts& input);
// Checks that need the opened device's description (a board profile's converter, ...), from
// execute_run once the device is open.
std::vector<Finding> preflight_device(const Scenario& sc, const dev::DeviceInfo& d);

}  // namespace fringe
