// Interface profiles (docs/signal-quality.md "Interface profiles"): named sets of bands that
// grade the signals' quality figures the way encoder testers do. Each band names a run-level
// signal metric (signal_vpp_a_v, signal_ab_ratio, signal_phase_deg, signal_tv_a_deg, ...) and
// gives the interface specification [lo, hi] and, optionally, a tighter mounting tolerance
// inside it. A figure within the mounting tolerance PASSes, within the specification only is
// MARGINAL, outside it (or not measured) FAILs. Profiles are JSON files
// (fixtures/interfaces/*.json) or inline objects, named by a scenario's "interface".
#pragma once

#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

namespace fringe {

struct InterfaceBand {
    std::string metric;                       // a run-level signal metric of the metric table
    std::optional<double> spec_lo, spec_hi;   // the interface specification (either side may be open)
    std::optional<double> mount_lo, mount_hi; // the mounting tolerance, inside the specification
    bool has_mounting = false;
};

struct InterfaceProfile {
    std::string name;
    std::string description;
    std::string source;  // where the numbers come from
    std::vector<InterfaceBand> bands;
};

// Parses and checks a profile (unknown keys, a metric that is not a signal metric, a band with
// lo > hi, a mounting band outside the specification: ConfigError naming the field under `path`).
InterfaceProfile interface_from_json(const nlohmann::json& j, const std::string& path);
void to_json(nlohmann::json& j, const InterfaceProfile& p);

}  // namespace fringe
