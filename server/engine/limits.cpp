#include "server/engine/limits.hpp"

#include <cmath>
#include <cstdio>
#include <cstdlib>

namespace fringe {

using nlohmann::json;

namespace {

// harmonic_<k>x_rad -> k (1..64), else 0
std::string fmt_g(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.4g", v);
    return b;
}

int harmonic_order(const std::string& name) {
    if (name.rfind("harmonic_", 0) != 0 || name.size() < 15 || name.compare(name.size() - 5, 5, "x_rad") != 0) return 0;
    const std::string digits = name.substr(9, name.size() - 14);
    if (digits.empty() || digits.size() > 2 || digits.find_first_not_of("0123456789") != std::string::npos || digits[0] == '0') return 0;
    const int k = std::atoi(digits.c_str());
    return k >= 1 && k <= 64 ? k : 0;
}

}  // namespace

std::optional<std::pair<double, double>> metric_interval(const std::string& name, const json& metrics, double value) {
    if (!metrics.is_object()) return std::nullopt;
    const json u = metrics.value("uncertainty", json());
    if (!u.is_object()) return std::nullopt;
    auto iv = [](const json& j) -> std::optional<std::pair<double, double>> {
        if (!j.is_array() || j.size() != 2 || !j[0].is_number() || !j[1].is_number()) return std::nullopt;
        return std::make_pair(j[0].get<double>(), j[1].get<double>());
    };
    // The same figure in other units: the interval scales with it.
    auto scaled = [&](const char* key, const char* stat) -> std::optional<std::pair<double, double>> {
        auto r = iv(u.value(key, json()));
        const json s = metrics.value(stat, json());
        if (!r || !s.is_object() || !s.value("rad", json()).is_number()) return std::nullopt;
        const double rad = s["rad"].get<double>();
        if (rad == 0) return std::nullopt;
        const double k = value / rad;
        return std::make_pair(std::min(r->first * k, r->second * k), std::max(r->first * k, r->second * k));
    };
    if (name == "rms_rad" || name == "rms_percent_period" || name == "rms_arcsec_mech") return scaled("rms_rad", "rms");
    if (name == "std_rad") return iv(u.value("std_rad", json()));
    if (name == "mean_rad") return iv(u.value("mean_rad", json()));
    if (name == "broadband_rms_rad") return iv(u.value("broadband_rms_rad", json()));
    // efficiency = bound / rms^2: its interval follows the rms's
    if (name == "efficiency") {
        const auto r = iv(u.value("rms_rad", json()));
        const json s = metrics.value("rms", json());
        if (!r || !s.is_object() || !s.value("rad", json()).is_number() || r->first <= 0) return std::nullopt;
        const double rms = s["rad"].get<double>();
        return std::make_pair(value * (rms / r->second) * (rms / r->second), value * (rms / r->first) * (rms / r->first));
    }
    if (const int k = harmonic_order(name)) {
        for (const auto& h : u.value("harmonics", json::array()))
            if (h.value("order", 0) == k) return iv(h.value("amplitude_rad", json()));
    }
    return std::nullopt;
}

const std::vector<MetricInfo>& metric_catalog() {
    static const std::vector<MetricInfo> m = [] {
        std::vector<MetricInfo> v = {
            {"rms_rad", "rad", "rms phase error (electrical)"},
            {"std_rad", "rad", "phase error standard deviation"},
            {"mean_rad", "rad", "mean phase error"},
            {"max_abs_rad", "rad", "largest |error|"},
            {"max_dev_rad", "rad", "largest |error - mean|"},
            {"rms_percent_period", "%", "rms error in % of a signal period"},
            {"rms_arcsec_mech", "arcsec", "rms error, mechanical arcseconds"},
            {"max_abs_arcsec_mech", "arcsec", "largest |error|, mechanical arcseconds"},
            {"slipped_samples", "samples", "samples off by more than pi (cycle slips)"},
            {"invalid_after_settle", "samples", "samples flagged invalid after the settle time"},
            {"omega_error_std_rad_s", "rad/s", "rate error standard deviation"},
            {"lock_time_s", "s", "time until the error stays within 0.1 rad"},
            {"efficiency", "", "bound variance / mean squared error"},
            {"scored_samples", "samples", "valid samples after the settle time (evidence)"},
            {"scored_cycles", "cycles", "electrical cycles of truth under the scored samples (evidence)"},
            {"valid_fraction", "", "valid share of the samples after the settle time (evidence)"},
            {"convention_violations", "findings", "output conventions broken: wrapped theta, degrees (evidence; docs/model.md)"},
            {"harmonic_power_fraction", "", "share of the error variance in the fitted harmonics"},
            {"broadband_rms_rad", "rad", "rms error left after the fitted harmonics"},
            {"abz_illegal_transitions", "transitions", "DUT ABZ readout: A and B changed together (docs/abz.md)"},
            {"abz_index_errors", "pulses", "DUT ABZ readout: index pulses where the count was off (docs/abz.md)"},
        };
        for (int k = 1; k <= 16; ++k)
            v.push_back({"harmonic_" + std::to_string(k) + "x_rad", "rad", std::to_string(k) + "x harmonic of the error (amplitude)"});
        // The run's truth alignment (output and input instruments on their own clocks).
        v.push_back({"alignment_delay_s", "s", "delay from the record's start to the output's first sample (alignment)", true});
        v.push_back({"clock_offset_ppm", "ppm", "generator clock relative to the digitizer's (alignment)", true});
        v.push_back({"alignment_residual", "", "alignment fit residual rms / recorded signal rms", true});
        v.push_back({"alignment_residual_rms_v", "V", "alignment fit residual rms", true});
        return v;
    }();
    return m;
}

std::optional<MetricInfo> find_metric(const std::string& name) {
    for (const auto& m : metric_catalog())
        if (m.name == name) return m;
    if (const int k = harmonic_order(name)) return MetricInfo{name, "rad", std::to_string(k) + "x harmonic of the error (amplitude)"};
    return std::nullopt;
}

std::optional<double> metric_value(const std::string& name, const json& metrics, const json& bounds, std::string* why) {
    auto none = [&](const std::string& w) -> std::optional<double> {
        if (why) *why = w;
        return std::nullopt;
    };
    if (!metrics.is_object()) return none("no metrics (the estimator was not scored)");
    auto num = [&](const json& j, const char* w) -> std::optional<double> {
        if (j.is_number()) return j.get<double>();
        return none(w);
    };
    auto stat = [&](const char* key, const char* unit) -> std::optional<double> {
        const json& s = metrics.value(key, json());
        if (!s.is_object()) return none("no scored samples");
        return num(s.value(unit, json()), "not defined for this encoder (mechanical units need lines per revolution)");
    };
    const json ev = metrics.value("evidence", json::object());
    if (name == "rms_rad") return stat("rms", "rad");
    if (name == "std_rad") return stat("std", "rad");
    if (name == "mean_rad") return stat("mean", "rad");
    if (name == "max_abs_rad") return stat("max_abs", "rad");
    if (name == "max_dev_rad") return stat("max_dev", "rad");
    if (name == "rms_percent_period") return stat("rms", "percent_period");
    if (name == "rms_arcsec_mech") return stat("rms", "arcsec_mech");
    if (name == "max_abs_arcsec_mech") return stat("max_abs", "arcsec_mech");
    if (name == "slipped_samples") return num(metrics.value("slipped_samples", json()), "no scored samples");
    if (name == "invalid_after_settle") return num(metrics.value("invalid_after_settle", json()), "not counted");
    if (name == "omega_error_std_rad_s") {
        if (metrics.contains("omega_nonfinite_samples")) return none("the rate estimate was not finite on some scored samples");
        if (!metrics.contains("omega_error")) return none("no rate truth or no rate estimate");
        return num(metrics["omega_error"].value("std_rad_s", json()), "no rate estimate");
    }
    if (name == "lock_time_s") return num(metrics.value("lock_time_s", json()), "never locked (the error did not stay within 0.1 rad to the end)");
    if (name == "efficiency") {
        if (!bounds.is_object()) return none("no bound (nothing scored, or no signal model)");
        if (bounds.value("efficiency_not_credible", json()).is_string()) return none(bounds["efficiency_not_credible"].get<std::string>());
        if (bounds.value("efficiency", json()).is_number()) return bounds["efficiency"].get<double>();
        return none("no efficiency: " + bounds.value("efficiency_against", std::string("no bound")));
    }
    if (name == "abz_illegal_transitions" || name == "abz_index_errors") {
        const json abz = metrics.value("abz", json());
        if (!abz.is_object()) return none("only a DUT read out by ABZ has it (estimator \"dut\" on a capture with a/b lines)");
        return num(abz.value(name == "abz_illegal_transitions" ? "illegal_transitions" : "index_errors", json()), "not counted");
    }
    if (name == "scored_samples") return num(ev.value("scored_samples", json()), "not counted");
    if (name == "scored_cycles") return num(ev.value("scored_cycles", json()), "not counted");
    if (name == "valid_fraction") return num(ev.value("valid_fraction", json()), "no samples after the settle time");
    if (name == "convention_violations") return num(metrics.value("convention_violations", json()), "not checked (no truth to compare the output with)");
    const json ha = metrics.value("harmonic_analysis", json::object());
    if (name == "harmonic_power_fraction") return num(ha.value("power_fraction", json()), "harmonics not fitted");
    if (name == "broadband_rms_rad") return num(ha.value("broadband_rms_rad", json()), "harmonics not fitted");
    if (const int k = harmonic_order(name)) {
        for (const auto& h : metrics.value("harmonics", json::array()))
            if (h.value("order", 0) == k) return num(h["amplitude"].value("rad", json()), "not fitted");
        const std::string note = ha.value("note", json()).is_string() ? ha["note"].get<std::string>() : "";
        return none(note.empty() ? "order " + std::to_string(k) + "x is above the orders fitted (scoring.max_harmonic)" : note);
    }
    return none("unknown metric");
}

std::optional<double> run_metric_value(const std::string& name, const json& a, std::string* why) {
    auto none = [&](const std::string& w) -> std::optional<double> {
        if (why) *why = w;
        return std::nullopt;
    };
    if (!a.is_object())
        return none("the run has no alignment (only runs whose device plays and records on its own clock are aligned: docs/alignment.md)");
    if (!a.value("ok", false)) return none("the alignment failed: " + (a.value("error", json()).is_string() ? a["error"].get<std::string>() : std::string("not run")));
    const char* key = name == "alignment_delay_s" ? "delay_s" : name == "clock_offset_ppm" ? "clock_offset_ppm"
                    : name == "alignment_residual" ? "residual_relative" : name == "alignment_residual_rms_v" ? "residual_rms_v" : nullptr;
    if (!key) return none("unknown metric");
    const json& v = a.value(key, json());
    if (!v.is_number()) return none("not measured");
    return v.get<double>();
}

json evaluate_limits(const Scenario& sc, const json& estimators, RunStatus status, Verdict& verdict, const json& alignment) {
    json out = json::array();
    verdict = Verdict::Pass;
    auto measure = [&](const std::string& label, const std::string& metric, std::optional<double> max, std::optional<double> min,
                       double marginal, bool implicit, const json& ej) {
        const auto mi = find_metric(metric);
        std::string why;
        const auto v = mi && mi->run_level ? run_metric_value(metric, alignment, &why)
                                           : metric_value(metric, ej.value("metrics", json()), ej.value("bounds", json()), &why);
        json mj{{"estimator", label}, {"metric", metric}, {"unit", mi ? mi->unit : ""}, {"value", v ? json(*v) : json()}};
        if (implicit) mj["implicit"] = true;
        json lim = json::object();
        if (max) lim["max"] = *max;
        if (min) lim["min"] = *min;
        lim["marginal_fraction"] = marginal;
        mj["limit"] = lim;
        Verdict o = Verdict::Pass;
        if (status != RunStatus::Done) o = Verdict::Error;
        else if (!v) {
            o = Verdict::Fail;  // what could not be measured never passes
            mj["reason"] = "not measured: " + why;
        } else if ((max && *v > *max) || (min && *v < *min)) o = Verdict::Fail;
        else if (max && *v > *max - marginal * std::fabs(*max)) o = Verdict::Marginal;
        else if (min && *v < *min + marginal * std::fabs(*min)) o = Verdict::Marginal;
        // Every error figure has a 95 % interval: a limit inside it is no confident decision.
        if (v && status == RunStatus::Done && !implicit) {
            if (const auto iv = metric_interval(metric, ej.value("metrics", json()), *v)) {
                mj["interval_95"] = json::array({iv->first, iv->second});
                auto inside = [&](const std::optional<double>& l) { return l && iv->first <= *l && *l <= iv->second; };
                if ((inside(max) || inside(min)) && (o == Verdict::Pass || o == Verdict::Fail)) {
                    mj["reason"] = std::string("the limit lies within the value's 95 % interval [") + fmt_g(iv->first) + ", " + fmt_g(iv->second) +
                                   "]: not a confident " + (o == Verdict::Pass ? "PASS" : "FAIL") + " (a longer run narrows it)";
                    o = Verdict::Marginal;
                }
            }
        }
        mj["outcome"] = to_string(o);
        verdict = worse(verdict, o);
        out.push_back(std::move(mj));
    };
    for (const auto& ej : estimators) {
        const std::string label = ej.value("label", "");
        const auto& r = sc.scoring;
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
    if (status == RunStatus::Error) verdict = Verdict::Error;
    if (status == RunStatus::Aborted || status == RunStatus::Interrupted) verdict = Verdict::Aborted;
    return out;
}

}  // namespace fringe
