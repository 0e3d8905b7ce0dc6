#include "server/engine/limits.hpp"

#include <cmath>
#include <cstdio>
#include <cstdlib>

namespace fringe {

using nlohmann::json;

namespace {

std::string fmt_g(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.4g", v);
    return b;
}

}  // namespace

json evaluate_limits(const Scenario& sc, const json& estimators, RunStatus status, Verdict& verdict, const json& run, bool has_truth) {
    json out = json::array();
    verdict = Verdict::Pass;
    // band: an interface profile's band (interface_profile.hpp): the limit is its specification,
    // and a value outside its mounting tolerance is MARGINAL instead of a marginal fraction.
    auto measure = [&](const std::string& label, const std::string& metric, std::optional<double> max, std::optional<double> min,
                       double marginal, bool implicit, const json& ej, const InterfaceBand* band = nullptr) {
        const auto mi = find_metric(metric);
        std::string why;
        const auto v = mi && mi->run_level ? run_metric_value(metric, run, &why)
                                           : lane_metric_value(metric, ej, &why);
        json mj{{"estimator", label}, {"metric", metric}, {"unit", mi ? mi->unit : ""}, {"value", v ? json(*v) : json()}};
        if (implicit) mj["implicit"] = true;
        json lim = json::object();
        if (max) lim["max"] = *max;
        if (min) lim["min"] = *min;
        auto range = [](const std::optional<double>& lo, const std::optional<double>& hi) {
            return json::array({lo ? json(*lo) : json(), hi ? json(*hi) : json()});
        };
        if (band) {
            mj["interface"] = sc.interface->name;
            mj["band"] = {{"spec", range(band->spec_lo, band->spec_hi)}};
            if (band->has_mounting) mj["band"]["mounting"] = range(band->mount_lo, band->mount_hi);
        } else {
            lim["marginal_fraction"] = marginal;
        }
        mj["limit"] = lim;
        Verdict o = Verdict::Pass;
        if (status != RunStatus::Done) o = Verdict::Error;
        else if (!v) {
            o = Verdict::Fail;  // what could not be measured never passes
            if (!has_truth && mi && !mi->run_level && metric.rfind("self_ref_", 0) != 0)
                why = "the capture has no truth (theta_true), so " + metric + " cannot be measured; the self_ref_* metrics measure the error without it";
            mj["reason"] = "not measured: " + why;
        } else if ((max && *v > *max) || (min && *v < *min)) o = Verdict::Fail;
        else if (band) {
            if (band->has_mounting && ((band->mount_lo && *v < *band->mount_lo) || (band->mount_hi && *v > *band->mount_hi))) o = Verdict::Marginal;
        } else if (max && *v > *max - marginal * std::fabs(*max)) o = Verdict::Marginal;
        else if (min && *v < *min + marginal * std::fabs(*min)) o = Verdict::Marginal;
        // Every error figure has a 95 % interval: a limit inside it is no confident decision.
        if (v && status == RunStatus::Done && !implicit) {
            if (const auto iv = lane_metric_interval(metric, ej, *v)) {
                mj["interval_95"] = json::array({iv->first, iv->second});
                auto inside = [&](const std::optional<double>& l) { return l && iv->first <= *l && *l <= iv->second; };
                if ((inside(max) || inside(min)) && (o == Verdict::Pass || o == Verdict::Fail)) {
                    mj["reason"] = std::string("the limit lies within the value's 95 % interval [") + fmt_g(iv->first) + ", " + fmt_g(iv->second) +
                                   "]: not a confident " + (o == Verdict::Pass ? "PASS" : "FAIL") + " (a longer run narrows it)";
                    o = Verdict::Marginal;
                }
            }
        }
        if (band && status == RunStatus::Done)
            mj["grade"] = !v                        ? "not measured"
                          : o == Verdict::Fail     ? "out of specification"
                          : o == Verdict::Marginal ? "within specification, outside mounting tolerance"
                          : band->has_mounting     ? "within mounting tolerance"
                                                   : "within specification";
        mj["outcome"] = to_string(o);
        verdict = worse(verdict, o);
        out.push_back(std::move(mj));
    };
    for (const auto& ej : estimators) {
        const std::string label = ej.value("label", "");
        const auto& r = sc.scoring;
        if (!has_truth) {  // the evidence the self-referenced figures rest on
            measure(label, "self_ref_samples", std::nullopt, static_cast<double>(r.min_scored_samples), 0.0, true, ej);
            if (r.min_scored_cycles > 0) measure(label, "self_ref_cycles", std::nullopt, r.min_scored_cycles, 0.0, true, ej);
            measure(label, "self_ref_valid_fraction", std::nullopt, r.min_valid_fraction, 0.0, true, ej);
            continue;
        }
        measure(label, "scored_samples", std::nullopt, static_cast<double>(r.min_scored_samples), 0.0, true, ej);
        if (r.min_scored_cycles > 0) measure(label, "scored_cycles", std::nullopt, r.min_scored_cycles, 0.0, true, ej);
        measure(label, "valid_fraction", std::nullopt, r.min_valid_fraction, 0.0, true, ej);
        // An estimator that slipped cycles or broke the output conventions (wrapped theta,
        // degrees) is broken whatever the user's limits say: these are evidence too.
        measure(label, "slipped_samples", static_cast<double>(r.max_slipped_samples), std::nullopt, 0.0, true, ej);
        measure(label, "convention_violations", 0.0, std::nullopt, 0.0, true, ej);
    }
    for (const auto& l : sc.limits) {
        if (const auto mi = find_metric(l.metric); mi && mi->run_level) {  // once for the run
            measure("run", l.metric, l.max, l.min, l.marginal_fraction, false, json::object());
            continue;
        }
        for (const auto& ej : estimators) {
            const std::string label = ej.value("label", "");
            if (l.estimator != "*" && l.estimator != label) continue;
            measure(label, l.metric, l.max, l.min, l.marginal_fraction, false, ej);
        }
    }
    // The signals graded against the scenario's interface profile: within the mounting tolerance
    // PASS, within the specification only MARGINAL, outside it or not measured FAIL.
    if (sc.interface)
        for (const auto& b : sc.interface->bands) measure("run", b.metric, b.spec_hi, b.spec_lo, 0.0, false, json::object(), &b);
    if (status == RunStatus::Error) verdict = Verdict::Error;
    if (status == RunStatus::Aborted || status == RunStatus::Interrupted) verdict = Verdict::Aborted;
    return out;
}

}  // namespace fringe
