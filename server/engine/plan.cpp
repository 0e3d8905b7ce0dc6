#include "server/engine/plan.hpp"

#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "server/engine/capture_run.hpp"
#include "server/engine/limits.hpp"
#include "signal_gen/base/config.hpp"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <vector>

namespace fringe {

namespace fs = std::filesystem;

namespace {

est::EstimatorConfig estimator_config(const Scenario& sc, const EstimatorSpec& spec) {
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = sc.sample_rate_hz;
    cfg.encoder = spec.encoder ? spec.encoder : sc.encoder_known ? std::optional(sc.encoder) : std::nullopt;
    cfg.params = spec.params;
    return cfg;
}

// Can this estimator be given an efficiency? (A tracker must declare its prior.)
std::string why_no_efficiency(const EstimatorSpec& spec, const est::Estimator* built) {
    if (est::traits_of(spec.name).child_process || !built) {
        const std::string model = spec.params.is_object() ? spec.params.value("model", std::string("unknown")) : "unknown";
        return model == "unknown" ? "the " + spec.name + " estimator declares no model: set params.model (memoryless, tracker-cv or tracker-ca) "
                                    "and, for a tracker, params.natural_freq_hz (docs/external-estimator.md)"
                                  : "";
    }
    if (built->bound_class() == est::BoundClass::Tracker && !built->prior()) return spec.label + " (" + spec.name + ") declares no tracking prior";
    return "";
}

// Each estimator built once (its parameters checked by its reset) and kept for the run; a
// child process is not started before the run, only its declared model checked.
void build_estimators(RunPlan& p) {
    const Scenario& sc = p.scenario;
    if (sc.estimators.empty()) throw ConfigError("estimators", "a run needs at least one estimator under test");
    p.estimators.resize(sc.estimators.size());
    for (std::size_t i = 0; i < sc.estimators.size(); ++i) {
        const auto& spec = sc.estimators[i];
        p.configs.push_back(estimator_config(sc, spec));
        try {
            const auto& info = est::find(spec.name);
            const Params params = resolve_params(info.params, spec.params);  // cheap checks first
            if (!info.traits.child_process) p.estimators[i] = est::make(spec.name, p.configs.back());
            else if (params.string("model").rfind("tracker", 0) == 0 && !(params.number("natural_freq_hz") > 0))
                throw ConfigError("params.natural_freq_hz", "a tracker's declared prior needs its natural frequency (> 0 Hz)");
        } catch (const ConfigError& e) {
            // An unknown estimator is the scenario's "name" key (est::find names the CLI's --estimator).
            if (e.field() == "estimator") throw ConfigError("estimators[" + std::to_string(i) + "].name", e.message());
            throw e.prefixed("estimators[" + std::to_string(i) + "]");
        }
    }
}

void check_limits(const RunPlan& p) {
    const Scenario& sc = p.scenario;
    for (std::size_t i = 0; i < sc.limits.size(); ++i) {
        const auto& l = sc.limits[i];
        const std::string path = "limits[" + std::to_string(i) + "]";
        if (!find_metric(l.metric)) {
            std::string known;
            for (const auto& m : metric_catalog())
                if (m.limitable) known += (known.empty() ? "" : ", ") + m.name;
            throw ConfigError(path + ".metric", "unknown metric '" + l.metric + "' (known: " + known + ", and harmonic_Nx_rad up to 64x)");
        }
        if (!find_metric(l.metric)->limitable)
            throw ConfigError(path + ".metric", "'" + l.metric + "' is a bound of the signal, not a figure of the estimator: a limit on it grades nothing");
        if (find_metric(l.metric)->run_level) {
            if (l.estimator != "*" && l.estimator != "run")
                throw ConfigError(path + ".estimator", "'" + l.metric + "' is measured once for the run (alignment, signal quality): leave estimator out or give \"run\"");
        } else if (l.estimator == "run") {
            throw ConfigError(path + ".estimator", "'" + l.metric + "' is a figure of each estimator, not of the run: give an estimator's label or \"*\"");
        } else if (l.estimator != "*") {
            bool found = false;
            for (const auto& e : sc.estimators) found |= e.label == l.estimator;
            found |= l.estimator == "dut";  // a DUT board's own position (step mode, an ABZ capture, device.dut)
            if (!found) throw ConfigError(path + ".estimator", "no estimator labelled '" + l.estimator + "' in this scenario");
        }
        // A limit that can never be measured is refused now, not failed later.
        if (l.metric == "efficiency") {
            if (l.estimator == "dut") throw ConfigError(path + ".estimator", "a DUT's own position has no efficiency (it declares no model)");
            for (std::size_t k = 0; k < sc.estimators.size(); ++k) {
                const auto& e = sc.estimators[k];
                if (l.estimator != "*" && l.estimator != e.label) continue;
                if (const std::string why = why_no_efficiency(e, p.estimators[k].get()); !why.empty())
                    throw ConfigError(path + ".metric", "efficiency cannot be computed for '" + e.label + "': " + why);
            }
        }
    }
}

// The form and settings of every device URI (nothing is opened); errors name "device",
// "device.output", "device.input" or "device.dut". Returns the input device's parts (the
// preflight reads a loopback's converter from them).
dev::UriParts check_device_uris(const Scenario& sc) {
    dev::UriParts input;
    for (const auto& [field, uri] : sc.device_uris()) {
        dev::UriParts parts;
        try {
            parts = dev::check_uri(uri);
        } catch (const ConfigError& e) {
            // check_uri names "device" or "device.<setting>": the same under this URI's field.
            const std::string f = e.field();
            throw ConfigError(f.rfind("device", 0) == 0 ? field + f.substr(6) : field, e.message());
        }
        if (parts.scheme == "loopback" && !parts.path.empty())
            throw ConfigError(field, "loopback takes no path (got '" + parts.path + "'); use loopback:?key=value");
        if (field == "device" || field == "device.input") input = parts;
    }
    if (sc.instruments && !sc.instruments->dut.empty() && dev::check_uri(sc.instruments->dut).scheme != "readout")
        throw ConfigError("device.dut", "the DUT's own position is read by a readout: device (readout:/path/x.sr?protocol=..., readout:tcp://host:port; "
                                        "docs/dut-readouts.md)");
    return input;
}

// The capture a capture: URI names: the same file by any path or link, or a byte-identical copy.
bool same_capture_file(const std::string& a_uri, const std::string& b_uri) {
    const auto path_of = [](const std::string& uri) {
        const std::string rest = uri.substr(std::string("capture:").size());
        return fs::path(rest.substr(0, rest.find('?')));
    };
    if (a_uri.rfind("capture:", 0) != 0 || b_uri.rfind("capture:", 0) != 0) return false;
    const fs::path a = path_of(a_uri), b = path_of(b_uri);
    if (a.lexically_normal() == b.lexically_normal()) return true;
    std::error_code ec;
    if (fs::equivalent(a, b, ec)) return true;
    const auto na = fs::file_size(a, ec);
    if (ec) return false;
    const auto nb = fs::file_size(b, ec);
    if (ec || na != nb) return false;
    std::ifstream fa(a, std::ios::binary), fb(b, std::ios::binary);
    std::vector<char> ba(1 << 16), bb(1 << 16);
    while (fa && fb) {
        fa.read(ba.data(), static_cast<std::streamsize>(ba.size()));
        fb.read(bb.data(), static_cast<std::streamsize>(bb.size()));
        if (fa.gcount() != fb.gcount() || !std::equal(ba.begin(), ba.begin() + fa.gcount(), bb.begin())) return false;
    }
    return fa.eof() && fb.eof();
}

// Two device URIs for the same device and settings ("loopback:" and "loopback:?").
bool same_device(const std::string& a, const std::string& b) {
    if (a == b) return true;
    try {
        const auto pa = dev::check_uri(a), pb = dev::check_uri(b);
        return pa.scheme == pb.scheme && pa.path == pb.path && pa.settings == pb.settings;
    } catch (const std::exception&) {
        return false;
    }
}

std::string before_device_uri(const Scenario& sc) { return sc.instruments ? std::string() : sc.device; }

// The entries of the correction table a Modbus board's profile declares (none: not such a board,
// or a URI or profile that does not load; those are named where the device is checked and opened).
std::optional<std::size_t> board_table_entries(const std::string& uri) {
    try {
        const dev::UriParts u = dev::check_uri(uri);
        if (u.scheme != "modbus+tcp" && u.scheme != "modbus+rtu") return std::nullopt;
        const dev::BoardProfile b = dev::load_board(u.settings.value("board", std::string("generic-aio")));
        if (const auto* t = b.find("correction_table_rad")) return static_cast<std::size_t>(t->count);
    } catch (const std::exception&) {
    }
    return std::nullopt;
}

// "calibrate": the lane is an atan2 or pll2 lane of this scenario without a correction of its own, the
// table fits the board it is written to, and the after pass runs on another capture than the
// before pass (docs/calibration.md "In one run"). A board's own table size is taken here.
void check_calibration(Scenario& sc) {
    if (!sc.calibrate) return;
    CalibrateSpec& c = *sc.calibrate;
    const EstimatorSpec* lane = nullptr;
    std::string labels;
    for (const auto& e : sc.estimators) {
        if (e.label == c.lane) lane = &e;
        labels += (labels.empty() ? "'" : ", '") + e.label + "'";
    }
    if (!lane) throw ConfigError("calibrate.lane", "no estimator labelled '" + c.lane + "' in this scenario (its lanes: " + labels + ")");
    // pll2 tracks the phase atan2 reads (docs/calibration.md): its correction is atan2's reading's.
    if (lane->name != "atan2" && lane->name != "pll2")
        throw ConfigError("calibrate.lane", "'" + c.lane + "' runs " + lane->name + ": " +
                                                "a correction can only be computed for atan2's reading of the signals (and applied to atan2 and pll2); "
                                                "name an atan2 or pll2 lane");
    if (lane->params.is_object() && lane->params.contains("correction") && !lane->params["correction"].is_null())
        throw ConfigError("calibrate.lane", "'" + c.lane + "' already applies a correction (params.correction): calibrate it without one");
    // A Modbus board whose profile declares a correction table takes the correction at its own
    // entry count (it is written to it between the passes); given, the count must be the board's.
    const std::string board_uri = c.verify.device.empty() ? before_device_uri(sc) : c.verify.device;
    if (const std::optional<std::size_t> n = board_table_entries(board_uri)) {
        if (c.table_size_given && c.table_size != *n)
            throw ConfigError("calibrate.table_size", std::to_string(c.table_size) + " entries, but the board the after pass runs on holds " + std::to_string(*n) +
                                                          " (its correction_table_rad count): leave table_size out, or give " + std::to_string(*n));
        c.table_size = *n;
    }
    c.table_size_given = true;  // as planned: the report's scenario says the size used
    const std::string before_device = sc.instruments ? std::string() : sc.device;
    const std::string after_device = c.verify.device.empty() ? before_device : c.verify.device;
    if (!c.verify.device.empty()) {
        if (sc.instruments) throw ConfigError("calibrate.verify.device", "not yet with separate output and input instruments");
        try {
            (void)dev::check_uri(c.verify.device);
        } catch (const ConfigError& e) {
            throw ConfigError("calibrate.verify.device", e.message());
        }
    }
    // Never verified on the capture it was computed on: a replayed capture is the same signals
    // whatever the seed, and the same seed and motion on a generator are the same noise. Compared
    // as what they mean, not as text: the same file by another path, link or copy, the same
    // device with its settings in another spelling, the same motion written another way.
    if (before_device.rfind("capture:", 0) == 0) {
        if (c.verify.device.empty())
            throw ConfigError("calibrate.verify.device", "the before pass replays a capture: name another capture to verify the correction on "
                                                         "(a correction verified on the capture it was computed on also fits its noise)");
        if (same_capture_file(before_device, after_device))
            throw ConfigError("calibrate.verify.device", "the same capture as the before pass (the same file, or a copy of it): a correction is verified on another capture");
    } else if (same_device(after_device, before_device) && c.verify.seed.value_or(sc.seed + 1) == sc.seed &&
               (!c.verify.motion || nlohmann::json(*c.verify.motion) == nlohmann::json(sc.motion))) {
        throw ConfigError("calibrate.verify.seed", "the scenario's own seed with its motion and device is the same capture as the before pass: "
                                                   "give another seed, or another motion");
    }
    // Another capture is read before anything runs: an unreadable one was found only after
    // the whole before pass, and named as a missing duration_s.
    if (!c.verify.device.empty() && c.verify.device.rfind("capture:", 0) == 0) {
        const dev::UriParts u = dev::check_uri(c.verify.device);
        try {
            CaptureReader reader(u.path, capture_options_from_uri(u.settings));
            CaptureData d;
            if (!reader.read(1, d) || d.size() == 0) throw std::runtime_error(u.path + ": no samples");
        } catch (const std::exception& e) {
            throw ConfigError("calibrate.verify.device", e.what());
        }
    }
}

void check_budget(const Scenario& sc, const RunBudget& b) {
    // In double: duration_s * sample_rate_hz may not fit an integer at all.
    // A calibrated run is two passes of it (the after pass on another capture of that length).
    const double passes = sc.calibrate ? 2.0 : 1.0;
    const double samples = sc.duration_s * sc.sample_rate_hz * passes;
    if (!(samples <= b.max_samples)) {
        char msg[256];
        std::snprintf(msg, sizeof msg, "duration_s %g s at sample_rate_hz %g Hz is %.4g samples%s; this service runs at most %.4g per run",
                      sc.duration_s, sc.sample_rate_hz, samples, sc.calibrate ? " over its before and after passes" : "", b.max_samples);
        throw RunTooLarge("too_many_samples", "duration_s", msg);
    }
    if (sc.estimators.size() > b.max_estimators)
        throw RunTooLarge("too_many_estimators", "estimators", "the scenario has " + std::to_string(sc.estimators.size()) +
                                                                   " estimators; this service runs at most " + std::to_string(b.max_estimators) + " per run");
    if (sc.limits.size() > b.max_limits)
        throw RunTooLarge("too_many_limits", "limits", "the scenario has " + std::to_string(sc.limits.size()) + " limits; this service takes at most " +
                                                           std::to_string(b.max_limits) + " per run");
}

}  // namespace

RunPlan plan_run(Scenario sc, const RunBudget& budget) {
    // A capture replayed, read once here: the preflight takes its motion from the capture, not
    // from the scenario's "motion" (left from the fixture a form started from), and a scenario
    // that left out the rate, the length or the encoder takes the capture's. A capture that
    // cannot be read is the run's fault when it opens the device, named there (or here, when
    // the scenario needs its length).
    std::optional<Finding> self_ref_check;
    if (!sc.instruments && sc.device.rfind("capture:", 0) == 0 && !sc.motion_from_capture) {
        std::optional<CaptureScan> scan;
        const dev::UriParts u = dev::check_uri(sc.device);  // a bad URI: its own error
        try {
            if (!u.path.empty()) scan = scan_capture(u.path, capture_options_from_uri(u.settings), sc.settle_s);
        } catch (const std::exception& e) {
            if (sc.length_from_capture || !sc.encoder_known)
                throw ConfigError(sc.length_from_capture ? "duration_s" : "encoder",
                                  std::string("not given, and the capture could not be read to take it from: ") + e.what());
        }
        if (scan) {
            if (!(sc.sample_rate_hz > 0)) sc.sample_rate_hz = scan->sample_rate_hz;
            if (!(sc.duration_s > 0)) sc.duration_s = static_cast<double>(scan->samples) / scan->sample_rate_hz;
            if (!sc.encoder_known && scan->meta.is_object() && scan->meta.contains("encoder")) {
                sc.encoder = encoder_from_json(scan->meta["encoder"], "capture.encoder");
                sc.encoder_known = true;
            }
            sc.motion = capture_motion(*scan, sc.settle_s, sc.encoder.lines_per_rev);
            sc.motion_from_capture = true;
            // Without truth (or asked for) the error is self-referenced: can this motion give it?
            if (!scan->has_truth || sc.scoring.self_reference) self_ref_check = self_reference_motion_check(*scan, sc.settle_s);
        }
        sc.length_from_capture = false;
        if (sc.samples() < 1) throw ConfigError("duration_s", "gives no samples at this sample rate");
    }
    check_budget(sc, budget);
    RunPlan p;
    p.scenario = std::move(sc);
    check_calibration(p.scenario);
    build_estimators(p);
    check_limits(p);
    const dev::UriParts input = check_device_uris(p.scenario);
    p.samples_per_cycle = min_samples_per_cycle(p.scenario);
    p.warnings = preflight(p.scenario, p.samples_per_cycle, input);
    if (self_ref_check) p.warnings.push_back(std::move(*self_ref_check));
    return p;
}

}  // namespace fringe
