#include "server/analysis/metrics.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>

namespace fringe {

using nlohmann::json;

namespace {

using Value = std::optional<double>;
using Interval = std::optional<std::pair<double, double>>;

Value none(std::string* why, const std::string& w) {
    if (why) *why = w;
    return std::nullopt;
}
// A figure that is not a finite number was not measured (an overflow is no value).
Value number(const json& j, std::string* why, const std::string& w) {
    if (j.is_number() && std::isfinite(j.get<double>())) return j.get<double>();
    if (j.is_number()) return none(why, "not finite (the computation overflowed)");
    return none(why, w);
}
const json& metrics_of(const json& entry) {
    static const json null;
    return entry.is_object() && entry.contains("metrics") ? entry["metrics"] : null;
}
const json& bounds_of(const json& entry) {
    static const json null;
    return entry.is_object() && entry.contains("bounds") ? entry["bounds"] : null;
}
json sub(const json& j, const char* k) { return j.is_object() ? j.value(k, json()) : json(); }

// harmonic_<k>x_rad -> k (1..64), else 0
int harmonic_order(const std::string& name) {
    if (name.rfind("harmonic_", 0) != 0 || name.size() < 15 || name.compare(name.size() - 5, 5, "x_rad") != 0) return 0;
    const std::string digits = name.substr(9, name.size() - 14);
    if (digits.empty() || digits.size() > 2 || digits.find_first_not_of("0123456789") != std::string::npos || digits[0] == '0') return 0;
    const int k = std::atoi(digits.c_str());
    return k >= 1 && k <= 64 ? k : 0;
}

Interval pair_of(const json& j) {
    if (!j.is_array() || j.size() != 2 || !j[0].is_number() || !j[1].is_number()) return std::nullopt;
    return std::make_pair(j[0].get<double>(), j[1].get<double>());
}
json uncertainty_of(const json& entry) {
    const json& m = metrics_of(entry);
    return m.is_object() && m.value("uncertainty", json()).is_object() ? m["uncertainty"] : json();
}

// The error statistics: metrics.<stat>.<unit> (angle_units in scoring.cpp).
std::function<Value(const json&, std::string*)> stat(const char* key, const char* unit) {
    return [key, unit](const json& e, std::string* why) -> Value {
        const json s = sub(metrics_of(e), key);
        if (!s.is_object()) return metrics_of(e).is_object() ? none(why, "no scored samples") : none(why, "no metrics (the estimator was not scored)");
        return number(s.value(unit, json()), why, "not defined for this encoder (mechanical units need lines per revolution)");
    };
}
// A count of the ABZ decoder (docs/abz.md): metrics.abz for a capture's a/b lines, or
// metrics.readout.abz for an ABZ device.dut.
std::function<Value(const json&, std::string*)> abz_count(const char* key) {
    return [key](const json& e, std::string* why) -> Value {
        json abz = sub(metrics_of(e), "abz");
        if (!abz.is_object()) abz = sub(sub(metrics_of(e), "readout"), "abz");
        if (!abz.is_object()) return none(why, "only a DUT read out by ABZ has it (a capture's a/b lines, or an ABZ device.dut)");
        return number(abz.value(key, json()), why, "not counted");
    };
}
std::function<Value(const json&, std::string*)> field(std::vector<const char*> path, std::string missing) {
    return [path, missing](const json& e, std::string* why) -> Value {
        const json& m = metrics_of(e);
        if (!m.is_object()) return none(why, "no metrics (the estimator was not scored)");
        json j = m;
        for (const char* k : path) j = sub(j, k);
        return number(j, why, missing);
    };
}
// The interval stored under uncertainty.<key>.
std::function<Interval(const json&, double)> stored(const char* key) {
    return [key](const json& e, double) { return pair_of(sub(uncertainty_of(e), key)); };
}
// The same figure as rms_rad in other units: its interval scales with it.
Interval rms_scaled(const json& e, double value) {
    const auto r = pair_of(sub(uncertainty_of(e), "rms_rad"));
    const json rad = sub(sub(metrics_of(e), "rms"), "rad");
    if (!r || !rad.is_number() || rad.get<double>() == 0) return std::nullopt;
    const double k = value / rad.get<double>();
    return std::make_pair(std::min(r->first * k, r->second * k), std::max(r->first * k, r->second * k));
}

Value alignment_value(const json& a, const char* key, std::string* why) {
    if (!a.is_object())
        return none(why, "the run has no alignment (only runs whose device plays and records on its own clock are aligned: docs/alignment.md)");
    if (!a.value("ok", false))
        return none(why, "the alignment failed: " + (a.value("error", json()).is_string() ? a["error"].get<std::string>() : std::string("not run")));
    return number(a.value(key, json()), why, "not measured");
}

MetricInfo harmonic_metric(int k) {
    MetricInfo m;
    m.name = "harmonic_" + std::to_string(k) + "x_rad";
    m.unit = "rad";
    m.description = std::to_string(k) + "x harmonic of the error (amplitude)";
    m.lanes = "every lane with truth, orders up to scoring.max_harmonic (16; at most 64)";
    m.uncertainty = "normal law of the fitted amplitude, effective samples = scored / correlation time";
    m.value = [k](const json& e, std::string* why) -> Value {
        const json& mj = metrics_of(e);
        if (!mj.is_object()) return none(why, "no metrics (the estimator was not scored)");
        for (const auto& h : mj.value("harmonics", json::array()))
            if (h.value("order", 0) == k) return number(sub(h.value("amplitude", json()), "rad"), why, "not fitted");
        const json ha = mj.value("harmonic_analysis", json::object());
        const std::string note = ha.is_object() && ha.value("note", json()).is_string() ? ha["note"].get<std::string>() : "";
        return none(why, note.empty() ? "order " + std::to_string(k) + "x is above the orders fitted (scoring.max_harmonic)" : note);
    };
    m.interval = [k](const json& e, double) -> Interval {
        for (const auto& h : sub(uncertainty_of(e), "harmonics").is_array() ? sub(uncertainty_of(e), "harmonics") : json::array())
            if (h.value("order", 0) == k) return pair_of(h.value("amplitude_rad", json()));
        return std::nullopt;
    };
    return m;
}

std::vector<MetricInfo> build_catalog() {
    const std::string every = "every lane with truth";
    const std::string no_iv = "none: an extreme value";
    const std::string count = "none: an exact count";
    auto M = [](std::string name, std::string unit, std::string desc, std::string lanes, std::string unc, std::string column,
                std::function<Value(const json&, std::string*)> value, std::function<Interval(const json&, double)> interval = nullptr) {
        MetricInfo m;
        m.name = std::move(name);
        m.unit = std::move(unit);
        m.description = std::move(desc);
        m.lanes = std::move(lanes);
        m.uncertainty = std::move(unc);
        m.column = std::move(column);
        m.value = std::move(value);
        m.interval = std::move(interval);
        return m;
    };
    std::vector<MetricInfo> v = {
        M("rms_rad", "rad", "rms phase error (electrical)", every,
          "delta method on the mean square error, effective samples = scored / correlation time (docs/model.md \"Evidence\")", "rms",
          stat("rms", "rad"), stored("rms_rad")),
        M("std_rad", "rad", "phase error standard deviation", every, "chi-square, effective samples = scored / correlation time", "",
          stat("std", "rad"), stored("std_rad")),
        M("mean_rad", "rad", "mean phase error", every, "normal law, effective samples = scored / correlation time", "mean",
          stat("mean", "rad"), stored("mean_rad")),
        M("max_abs_rad", "rad", "largest |error|", every, no_iv, "max |e|", stat("max_abs", "rad")),
        M("max_dev_rad", "rad", "largest |error - mean|", every, no_iv, "", stat("max_dev", "rad")),
        M("rms_percent_period", "%", "rms error in % of a signal period", every, "rms_rad's, scaled", "",
          stat("rms", "percent_period"), rms_scaled),
        M("rms_arcsec_mech", "arcsec", "rms error, mechanical arcseconds", every + " of an encoder with lines per revolution",
          "rms_rad's, scaled", "", stat("rms", "arcsec_mech"), rms_scaled),
        M("max_abs_arcsec_mech", "arcsec", "largest |error|, mechanical arcseconds", every + " of an encoder with lines per revolution", no_iv,
          "", stat("max_abs", "arcsec_mech")),
        M("slipped_samples", "samples", "samples off by more than pi (cycle slips; evidence)", every, count, "slipped",
          field({"slipped_samples"}, "no scored samples")),
        M("invalid_after_settle", "samples", "samples flagged invalid after the settle time", every, count, "",
          field({"invalid_after_settle"}, "not counted")),
        M("omega_error_std_rad_s", "rad/s", "rate error standard deviation", "lanes with a rate estimate, on signals with rate truth", "none",
          "", [](const json& e, std::string* why) -> Value {
              const json& m = metrics_of(e);
              if (!m.is_object()) return none(why, "no metrics (the estimator was not scored)");
              if (m.contains("omega_nonfinite_samples")) return none(why, "the rate estimate was not finite on some scored samples");
              if (!m.contains("omega_error")) return none(why, "no rate truth or no rate estimate");
              return number(sub(m["omega_error"], "std_rad_s"), why, "no rate estimate");
          }),
        M("lock_time_s", "s", "time until the error stays within 0.1 rad", every, "none: a first-passage time", "lock time",
          field({"lock_time_s"}, "never locked (the error did not stay within 0.1 rad to the end)")),
        M("efficiency", "", "bound variance / mean squared error (1: at the Cramer-Rao bound)",
          "lanes whose signal has a model to bound (docs/model.md \"Bounds\")", "rms_rad's, through efficiency = bound / rms^2", "efficiency",
          [](const json& e, std::string* why) -> Value {
              const json& b = bounds_of(e);
              if (!b.is_object()) return none(why, "no bound (nothing scored, or no signal model)");
              if (b.value("efficiency_not_credible", json()).is_string()) return none(why, b["efficiency_not_credible"].get<std::string>());
              if (b.value("efficiency", json()).is_number()) return number(b["efficiency"], why, "not measured");
              return none(why, "no efficiency: " + b.value("efficiency_against", std::string("no bound")));
          },
          [](const json& e, double value) -> Interval {
              const auto r = pair_of(sub(uncertainty_of(e), "rms_rad"));
              const json rms = sub(sub(metrics_of(e), "rms"), "rad");
              if (!r || !rms.is_number() || r->first <= 0) return std::nullopt;
              const double x = rms.get<double>();
              return std::make_pair(value * (x / r->second) * (x / r->second), value * (x / r->first) * (x / r->first));
          }),
        M("per_sample_crb_rad", "rad", "Cramer-Rao bound of one sample's phase (a bound, not an error)",
          "lanes whose signal has a model to bound", "none: computed from the model", "per-sample CRB",
          [](const json& e, std::string* why) { return number(sub(bounds_of(e), "per_sample_crb_rad"), why, "no bound (nothing scored, or no signal model)"); }),
        M("pcrb_rad", "rad", "posterior Cramer-Rao bound of a tracking estimator (a bound, not an error)",
          "lanes whose signal has a model to bound", "none: computed from the model", "PCRB",
          [](const json& e, std::string* why) { return number(sub(bounds_of(e), "pcrb_rad"), why, "no bound (nothing scored, or no signal model)"); }),
        M("scored_samples", "samples", "valid samples after the settle time (evidence)", "every lane", count, "scored samples",
          field({"evidence", "scored_samples"}, "not counted")),
        M("scored_cycles", "cycles", "electrical cycles of truth under the scored samples (evidence)", "every lane", "none: counted from truth",
          "scored cycles", field({"evidence", "scored_cycles"}, "not counted")),
        M("valid_fraction", "", "valid share of the samples after the settle time (evidence)", "every lane", "none: an exact ratio", "valid",
          field({"evidence", "valid_fraction"}, "no samples after the settle time")),
        M("convention_violations", "findings", "output conventions broken: wrapped theta, degrees (evidence; docs/model.md)", every, count, "",
          field({"convention_violations"}, "not checked (no truth to compare the output with)")),
        M("harmonic_power_fraction", "", "share of the error variance in the fitted harmonics", every, "none", "",
          field({"harmonic_analysis", "power_fraction"}, "harmonics not fitted")),
        M("broadband_rms_rad", "rad", "rms error left after the fitted harmonics", every,
          "chi-square, effective samples = scored / correlation time", "", field({"harmonic_analysis", "broadband_rms_rad"}, "harmonics not fitted"),
          stored("broadband_rms_rad")),
        M("abz_illegal_transitions", "transitions", "DUT ABZ readout: A and B changed together (docs/abz.md)",
          "the dut lane of a capture with a/b lines or of an ABZ device.dut", count, "", abz_count("illegal_transitions")),
        M("abz_index_errors", "pulses", "DUT ABZ readout: index pulses where the count was off (docs/abz.md)",
          "the dut lane of a capture with a/b lines or of an ABZ device.dut", count, "", abz_count("index_errors")),
        M("abz_missed_index", "pulses", "DUT ABZ readout: the count crossed the index cell with no Z pulse (docs/abz.md)",
          "the dut lane of a capture with a/b/z lines or of an ABZ device.dut with z", count, "", abz_count("missed_index")),
        M("dut_wire_errors", "words", "DUT readout: words invalid on the wire, every cause (bad CRC, short or long frames, error bit, malformed lines; "
          "docs/dut-readouts.md)", "the dut lane of a run with device.dut", count, "", [](const json& e, std::string* why) -> Value {
              const json ro = sub(metrics_of(e), "readout");
              if (!ro.is_object()) return none(why, "only a DUT read out by its own device has it (device.dut)");
              if (ro.contains("abz")) {  // every A/B/Z fault: illegal transitions, index pulses at the wrong count, missed ones
                  const json abz = sub(ro, "abz");
                  double total = 0;
                  for (const char* k : {"illegal_transitions", "index_errors", "missed_index"}) {
                      if (!abz.value(k, json()).is_number()) return none(why, "not counted");
                      total += abz[k].get<double>();
                  }
                  return number(json(total), why, "not counted");
              }
              // Invalid words, and lines that made no word at all.
              if (!ro.value("invalid_words", json()).is_number()) return none(why, "not counted");
              return number(json(ro["invalid_words"].get<double>() + ro.value("malformed_lines", 0.0)), why, "not counted");
          }),
        M("dut_crc_errors", "words", "DUT readout: words with a bad CRC (BiSS-C; docs/dut-readouts.md)", "the dut lane of a run with device.dut", count, "",
          [](const json& e, std::string* why) -> Value {
              const json ro = sub(metrics_of(e), "readout");
              if (!ro.is_object()) return none(why, "only a DUT read out by its own device has it (device.dut)");
              return number(ro.value("crc_errors", json()), why, "the protocol carries no CRC");
          }),
        M("dut_rms_no_latency_rad", "rad", "DUT readout: rms error of its words with the fitted latency taken out (its interpolation "
          "apart from its delay; docs/dut-readouts.md)", "the dut lane of a run with device.dut, on a moving motion", "none", "rms w/o latency",
          [](const json& e, std::string* why) -> Value {
              const json ro = sub(metrics_of(e), "readout");
              if (!ro.is_object()) return none(why, "only a DUT read out by its own device has it (device.dut)");
              return number(ro.value("rms_without_latency_rad", json()), why, "not measured: the motion did not move while words were scored");
          }),
        M("dut_latency_s", "s", "DUT readout: the age of the position a word carries at its latch instant (least squares of its error "
          "against the true rate; docs/dut-readouts.md)", "the dut lane of a run with device.dut, on a moving motion", "none: a fit", "latency",
          [](const json& e, std::string* why) -> Value {
              const json ro = sub(metrics_of(e), "readout");
              if (!ro.is_object()) return none(why, "only a DUT read out by its own device has it (device.dut)");
              return number(ro.value("latency_s", json()), why, "not measured: the motion did not move while words were scored");
          }),
    };
    // The bounds describe the signal, not the estimator: a limit on them would grade nothing.
    for (auto& m : v) {
        if (m.name == "per_sample_crb_rad" || m.name == "pcrb_rad") m.limitable = false;
        if (m.name == "per_sample_crb_rad" || m.name == "pcrb_rad" || m.name == "efficiency") m.group = "bound";
        if (m.name == "scored_samples" || m.name == "scored_cycles" || m.name == "valid_fraction" || m.name == "slipped_samples" ||
            m.name == "convention_violations" || m.name == "invalid_after_settle")
            m.group = "evidence";
    }
    for (int k = 1; k <= 16; ++k) v.push_back(harmonic_metric(k));
    // The error without truth (self_reference.hpp, docs/self-reference.md): against a reference
    // built from the signals themselves, labelled self-referenced wherever it is shown.
    const std::string self_lanes = "every lane of a capture without truth, or of a run with scoring.self_reference";
    // The lane's self-referenced analysis (null, and why, when the run did not make one or,
    // measured_only, when it measured nothing); a figure's 95 % interval is +- 1.96 u.
    auto self_ref = [](const json& e, std::string* why, bool measured_only) -> json {
        const json sr = sub(sub(e, "analysers"), "self_reference");
        if (!sr.is_object()) {
            none(why, "not measured: the run had truth and did not ask for it (scoring.self_reference)");
            return json();
        }
        if (measured_only && sr.value("measured", false) != true) {
            none(why, sr.value("why_not", json()).is_string() ? sr["why_not"].get<std::string>() : std::string("not measured"));
            return json();
        }
        return sr;
    };
    auto harmonic_of = [](const json& sr, int k) -> json {
        for (const auto& h : sr.value("harmonics", json::array()))
            if (h.value("order", 0) == k) return h;
        return json();
    };
    auto normal95 = [](double value, const json& u) -> Interval {
        if (!u.is_number()) return std::nullopt;
        return std::make_pair(std::max(0.0, value - 1.96 * u.get<double>()), value + 1.96 * u.get<double>());
    };
    v.push_back(M("self_ref_rms_rad", "rad", "rms error about its mean, self-referenced (no truth: against the signals' own lag-free phase)",
                  self_lanes, "normal law, the standard uncertainty from the fit with correlated residuals (docs/self-reference.md)", "self-ref rms",
                  [self_ref](const json& e, std::string* why) -> Value {
                      const json sr = self_ref(e, why, true);
                      return sr.is_null() ? std::nullopt : number(sr.value("rms_rad", json()), why, "not measured");
                  },
                  [self_ref, normal95](const json& e, double value) {
                      return normal95(value, sub(self_ref(e, nullptr, true), "rms_u_rad"));
                  }));
    // Evidence of a run without truth: what the self-referenced figures rest on.
    auto self_field = [self_ref](const char* key) {
        return [self_ref, key](const json& e, std::string* why) -> Value {
            const json sr = self_ref(e, why, false);
            return sr.is_null() ? std::nullopt : number(sr.value(key, json()), why, "not counted");
        };
    };
    using Row = std::array<const char*, 5>;  // name, unit, meaning, uncertainty, key
    const Row evidence_rows[] = {
        {"self_ref_samples", "samples", "samples in the self-referenced windows (evidence without truth)", "none: an exact count", "samples"},
        {"self_ref_cycles", "cycles", "electrical periods swept by the self-referenced windows (evidence without truth)",
         "none: counted from the signals", "cycles"},
        {"self_ref_valid_fraction", "", "share of the samples after the settle time the estimator vouched for (evidence without truth)",
         "none: an exact ratio", "valid_fraction"}};
    for (const auto& [name, unit, desc, unc, key] : evidence_rows) {
        MetricInfo m = M(name, unit, desc, self_lanes, unc, "", self_field(key));
        m.group = "evidence";
        v.push_back(std::move(m));
    }
    for (int k = 1; k <= 4; ++k)
        v.push_back(M("self_ref_harmonic_" + std::to_string(k) + "x_rad", "rad",
                      std::to_string(k) + "x harmonic of the error against the electrical angle, self-referenced", self_lanes,
                      "normal law of the fitted amplitude (docs/self-reference.md)", "",
                      [self_ref, harmonic_of, k](const json& e, std::string* why) -> Value {
                          const json sr = self_ref(e, why, true);
                          return sr.is_null() ? std::nullopt : number(sub(harmonic_of(sr, k), "amplitude_rad"), why, "not fitted");
                      },
                      [self_ref, harmonic_of, normal95, k](const json& e, double value) {
                          return normal95(value, sub(harmonic_of(self_ref(e, nullptr, true), k), "u_rad"));
                      }));
    // The run's truth alignment (output and input instruments on their own clocks).
    const std::string aligned = "the run, once (estimator \"run\"), when its device plays and records on its own clock (docs/alignment.md)";
    auto R = [&](std::string name, std::string unit, std::string desc, const char* key) {
        MetricInfo m;
        m.name = std::move(name);
        m.unit = std::move(unit);
        m.description = std::move(desc);
        m.run_level = true;
        m.lanes = aligned;
        m.uncertainty = "none: a fit";
        m.value = [key](const json& run, std::string* why) { return alignment_value(sub(run, "alignment"), key, why); };
        return m;
    };
    v.push_back(R("alignment_delay_s", "s", "delay from the record's start to the output's first sample (alignment)", "delay_s"));
    v.push_back(R("clock_offset_ppm", "ppm", "generator clock relative to the digitizer's (alignment)", "clock_offset_ppm"));
    v.push_back(R("alignment_residual", "", "alignment fit residual rms / recorded signal rms", "residual_relative"));
    v.push_back(R("alignment_residual_rms_v", "V", "alignment fit residual rms", "residual_rms_v"));
    // The signals' quality (signal_quality.hpp, docs/signal-quality.md): means over the run's
    // whole electrical periods, from the signals alone.
    auto S = [&](std::string name, std::string unit, std::string desc, std::vector<const char*> path) {
        MetricInfo m;
        m.name = std::move(name);
        m.unit = std::move(unit);
        m.description = std::move(desc);
        m.run_level = true;
        m.group = "signal";
        m.lanes = "the run, once (estimator \"run\"), from the signals of every run and capture (truth not needed)";
        m.uncertainty = "none yet: a mean over the run's periods (their spread is in report signal.*_range)";
        m.value = [path](const json& run, std::string* why) -> Value {
            const json sq = sub(run, "signal");
            if (!sq.is_object()) return none(why, "the run has no signal analysis (a report older than fringe 0.13, or no samples)");
            if (sq.value("periods", 0) == 0)
                return none(why, sq.value("note", json()).is_string() ? sq["note"].get<std::string>() : std::string("no whole electrical period"));
            json j = sq;
            for (const char* k : path) j = sub(j, k);
            return number(j, why, "not measured");
        };
        return m;
    };
    v.push_back(S("signal_vpp_a_v", "V", "A (sin) channel amplitude, peak to peak (fundamental)", {"a", "vpp_v"}));
    v.push_back(S("signal_vpp_b_v", "V", "B (cos) channel amplitude, peak to peak (fundamental)", {"b", "vpp_v"}));
    v.push_back(S("signal_ab_ratio", "", "amplitude ratio A / B (1 ideal)", {"ab_ratio"}));
    v.push_back(S("signal_phase_deg", "deg", "phase between A and B (90 ideal)", {"phase_deg"}));
    v.push_back(S("signal_phase_error_deg", "deg", "phase between A and B minus 90", {"phase_error_deg"}));
    v.push_back(S("signal_offset_a_v", "V", "A channel offset", {"a", "offset_v"}));
    v.push_back(S("signal_offset_b_v", "V", "B channel offset", {"b", "offset_v"}));
    v.push_back(S("signal_offset_a_percent", "%", "A channel offset, % of its amplitude", {"a", "offset_percent"}));
    v.push_back(S("signal_offset_b_percent", "%", "B channel offset, % of its amplitude", {"b", "offset_percent"}));
    v.push_back(S("signal_tv_a_deg", "deg", "A channel on/off ratio TV: time above 0 V minus 180 deg", {"a", "tv_deg"}));
    v.push_back(S("signal_tv_b_deg", "deg", "B channel on/off ratio TV: time above 0 V minus 180 deg", {"b", "tv_deg"}));
    v.push_back(S("signal_sym_a", "", "A channel asymmetry |P - N| / (2 M)", {"a", "sym"}));
    v.push_back(S("signal_sym_b", "", "B channel asymmetry |P - N| / (2 M)", {"b", "sym"}));
    v.push_back(S("signal_thd_a_percent", "%", "A channel harmonic distortion h2..h8, % of the fundamental", {"a", "thd_percent"}));
    v.push_back(S("signal_thd_b_percent", "%", "B channel harmonic distortion h2..h8, % of the fundamental", {"b", "thd_percent"}));
    v.push_back(S("signal_noise_a_v", "V", "A channel noise about its fitted shape, rms", {"a", "noise_v_rms"}));
    v.push_back(S("signal_noise_b_v", "V", "B channel noise about its fitted shape, rms", {"b", "noise_v_rms"}));
    v.push_back(S("signal_radius_min_v", "V", "smallest sqrt(A^2 + B^2) of any sample", {"radius_min_v"}));
    v.push_back(S("signal_radius_max_v", "V", "largest sqrt(A^2 + B^2) of any sample", {"radius_max_v"}));
    for (auto& m : v)
        if (m.name == "signal_radius_min_v" || m.name == "signal_radius_max_v") m.uncertainty = "none: an extreme value";
    v.push_back(S("signal_freq_hz", "Hz", "signal (electrical) frequency, mean over the periods", {"freq_hz"}));
    for (auto& m : v) {
        if (m.name == "signal_vpp_a_v") m.column = "A pp";
        if (m.name == "signal_vpp_b_v") m.column = "B pp";
        if (m.name == "signal_ab_ratio") m.column = "A/B";
        if (m.name == "signal_phase_deg") m.column = "phase";
        if (m.name == "signal_offset_a_v") m.column = "offset A";
        if (m.name == "signal_offset_b_v") m.column = "offset B";
        if (m.name == "signal_tv_a_deg") m.column = "TV A";
        if (m.name == "signal_tv_b_deg") m.column = "TV B";
        if (m.name == "signal_thd_a_percent") m.column = "THD A";
        if (m.name == "signal_thd_b_percent") m.column = "THD B";
        if (m.name == "signal_noise_a_v") m.column = "noise A";
        if (m.name == "signal_noise_b_v") m.column = "noise B";
        if (m.name == "signal_radius_min_v") m.column = "radius min";
        if (m.name == "signal_radius_max_v") m.column = "radius max";
        if (m.name == "signal_freq_hz") m.column = "frequency";
    }
    return v;
}

}  // namespace

const std::vector<MetricInfo>& metric_catalog() {
    static const std::vector<MetricInfo> m = build_catalog();
    return m;
}

std::optional<MetricInfo> find_metric(const std::string& name) {
    for (const auto& m : metric_catalog())
        if (m.name == name) return m;
    if (const int k = harmonic_order(name)) return harmonic_metric(k);
    return std::nullopt;
}

std::vector<const MetricInfo*> summary_metrics(bool run_level) {
    std::vector<const MetricInfo*> out;
    for (const auto& m : metric_catalog())
        if (!m.column.empty() && m.run_level == run_level) out.push_back(&m);
    return out;
}

std::optional<double> metric_value(const std::string& name, const json& metrics, const json& bounds, std::string* why) {
    const auto m = find_metric(name);
    if (!m || m->run_level) return none(why, "unknown metric");
    if (!metrics.is_object()) return none(why, "no metrics (the estimator was not scored)");
    return m->value(json{{"metrics", metrics}, {"bounds", bounds}}, why);
}

std::optional<double> lane_metric_value(const std::string& name, const json& entry, std::string* why) {
    const auto m = find_metric(name);
    if (!m || m->run_level) return none(why, "unknown metric");
    if (!entry.is_object() || !entry.value("metrics", json()).is_object()) return none(why, "no metrics (the estimator was not scored)");
    return m->value(entry, why);
}

std::optional<std::pair<double, double>> lane_metric_interval(const std::string& name, const json& entry, double value) {
    const auto m = find_metric(name);
    if (!m || !m->interval || !entry.is_object()) return std::nullopt;
    return m->interval(entry, value);
}

std::optional<double> run_metric_value(const std::string& name, const json& run, std::string* why) {
    const auto m = find_metric(name);
    if (!m || !m->run_level) return none(why, "unknown metric");
    return m->value(run, why);
}

std::optional<std::pair<double, double>> metric_interval(const std::string& name, const json& metrics, double value) {
    const auto m = find_metric(name);
    if (!m || !m->interval || !metrics.is_object()) return std::nullopt;
    return m->interval(json{{"metrics", metrics}}, value);
}

std::vector<MetricCell> report_metrics(const json& report) {
    std::vector<MetricCell> out;
    const json ests = report.is_object() && report.value("estimators", json()).is_array() ? report["estimators"] : json::array();
    for (const auto& info : metric_catalog()) {
        if (info.run_level) {
            MetricCell c{&info, "run", info.value(report, nullptr), std::nullopt, ""};
            if (!c.value) info.value(report, &c.why);
            out.push_back(std::move(c));
            continue;
        }
        for (const auto& e : ests) {
            MetricCell c{&info, e.is_object() && e.value("label", json()).is_string() ? e["label"].get<std::string>() : std::string("?"), {}, {}, ""};
            c.value = info.value(e, &c.why);
            if (c.value && info.interval) c.interval_95 = info.interval(e, *c.value);
            out.push_back(std::move(c));
        }
    }
    return out;
}

namespace {
json info_json(const MetricInfo& m) {
    json j{{"name", m.name}, {"unit", m.unit}, {"description", m.description}, {"lanes", m.lanes},
           {"scope", m.run_level ? "run" : "estimator"}, {"limitable", m.limitable}, {"uncertainty", m.uncertainty}, {"group", m.group}};
    if (!m.column.empty()) j["column"] = m.column;
    return j;
}
}  // namespace

json report_metrics_json(const json& report) {
    json lanes = json::array();
    for (const auto& e : report.is_object() ? report.value("estimators", json::array()) : json::array())
        lanes.push_back(e.is_object() && e.value("label", json()).is_string() ? e["label"].get<std::string>() : std::string("?"));
    lanes.push_back("run");
    json metrics = json::array();
    const auto cells = report_metrics(report);
    for (const auto& m : metric_catalog()) {
        json j = info_json(m);
        j["values"] = json::object();
        for (const auto& c : cells) {
            if (c.info != &m) continue;
            json v{{"value", c.value ? json(*c.value) : json()}};
            if (c.interval_95) v["interval_95"] = json::array({c.interval_95->first, c.interval_95->second});
            if (!c.value) v["why"] = c.why;
            j["values"][c.lane] = std::move(v);
        }
        metrics.push_back(std::move(j));
    }
    return {{"lanes", lanes}, {"metrics", metrics}};
}

json metric_table_json() {
    json out = json::array();
    for (const auto& m : metric_catalog()) out.push_back(info_json(m));
    return out;
}

std::string metric_table_markdown() {
    auto cell = [](const std::string& s) {
        std::string o;
        for (char c : s) o += c == '|' ? std::string("\\|") : std::string(1, c);
        return o;
    };
    std::string s = "| metric | unit | meaning | lanes | limit | 95 % interval |\n| --- | --- | --- | --- | --- | --- |\n";
    for (const auto& m : metric_catalog())
        s += "| `" + m.name + "` | " + (m.unit.empty() ? "1" : cell(m.unit)) + " | " + cell(m.description) + " | " + cell(m.lanes) + " | " +
             (m.limitable ? "yes" : "no") + " | " + cell(m.uncertainty) + " |\n";
    s += "\n`harmonic_Nx_rad` is accepted for any order N from 1 to 64 (fitted up to `scoring.max_harmonic`).\n";
    return s;
}

}  // namespace fringe
