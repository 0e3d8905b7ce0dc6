#include "server/engine/report.hpp"

#ifndef FRINGE_VERSION
#define FRINGE_VERSION "dev"
#endif

namespace fringe {

using nlohmann::json;

void to_json(json& j, const EstimatorReport& e) {
    json metrics = to_json(e.metrics, e.lines_per_rev);
    if (e.abz) metrics["abz"] = *e.abz;
    if (e.readout) metrics["readout"] = *e.readout;
    metrics["convention_violations"] = e.convention_violations;
    json diagnosis = json::array();
    for (const auto& d : e.diagnosis) diagnosis.push_back({{"code", d.code}, {"message", d.message}});
    j = json{{"label", e.label}, {"name", e.name}, {"params", e.params}, {"state", e.state}, {"metrics", std::move(metrics)},
             {"spectrum", e.spectrum}, {"bounds", e.bounds}, {"diagnosis", std::move(diagnosis)}};
    if (!e.analysers.empty()) j["analysers"] = e.analysers;
}

json estimators_json(const std::vector<EstimatorReport>& lanes) {
    json out = json::array();
    for (const auto& e : lanes) out.push_back(e);
    return out;
}

void to_json(json& j, const RunReport& r) {
    json device = nullptr;
    if (r.device) {
        device = *r.device;
        if (r.device_output) device["output"] = *r.device_output;
        if (r.device_input) device["input"] = *r.device_input;
    }
    json warnings = json::array();
    for (const auto& w : r.warnings) warnings.push_back(w);
    j = json{{"schema", RunReport::kSchema},
             {"schema_version", RunReport::kSchemaVersion},
             {"fringe_version", FRINGE_VERSION},
             {"id", r.id},
             {"started_at", r.started_at},
             {"finished_at", r.finished_at},
             {"wall_s", r.wall_s},
             {"scenario", r.scenario},
             {"seed", r.scenario.seed},
             {"device", std::move(device)},
             {"alignment", r.alignment},
             {"signal", r.signal},
             {"status", to_string(r.status)},
             {"verdict", r.verdict ? json(to_string(*r.verdict)) : json()},
             {"error", r.error.empty() ? json() : json(r.error)},
             {"warnings", std::move(warnings)},
             {"samples", {{"planned", r.samples_planned}, {"processed", r.samples_processed}}},
             {"estimators", estimators_json(r.estimators)},
             {"measurements", r.measurements},
             {"traces", r.traces}};
    if (!r.provenance.is_null()) j["provenance"] = r.provenance;
    if (!r.capture.is_null()) j["capture"] = r.capture;
    if (!r.calibration.is_null()) j["calibration"] = r.calibration;
}

}  // namespace fringe
