#include "server/engine/scenario.hpp"
#include "server/engine/scenario_keys.hpp"

#include "signal_gen/base/config.hpp"
#include "signal_gen/base/json_bounded.hpp"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace fringe {

using nlohmann::json;
namespace fs = std::filesystem;

std::uint64_t Scenario::samples() const {
    return static_cast<std::uint64_t>(std::llround(duration_s * sample_rate_hz));
}

std::string Scenario::device_label() const {
    if (!instruments) return device;
    return instruments->output == instruments->input ? instruments->output : instruments->output + " -> " + instruments->input;
}

std::vector<std::pair<std::string, std::string>> Scenario::device_uris() const {
    if (!instruments) return {{"device", device}};
    std::vector<std::pair<std::string, std::string>> v{{"device.output", instruments->output}, {"device.input", instruments->input}};
    if (!instruments->dut.empty()) v.push_back({"device.dut", instruments->dut});
    return v;
}

json load_json_file(const std::string& path) {
    // a directory opens as a stream on Linux and only fails when read (found by fuzz_config:
    // a scenario whose "encoder" is "" names its own folder)
    std::error_code ec;
    if (fs::is_directory(path, ec)) throw ConfigError("", "'" + path + "' is a directory, not a JSON file");
    // A device or a FIFO (/dev/zero, a pipe) never ends or never answers: only regular files,
    // and no larger than any scenario, profile or sweep needs.
    constexpr std::uintmax_t kMaxJsonFileBytes = 16u << 20;
    if (fs::exists(path, ec) && !fs::is_regular_file(path, ec)) throw ConfigError("", "'" + path + "' is not a regular file (a device, FIFO or socket), not a JSON file");
    if (const auto size = fs::file_size(path, ec); !ec && size > kMaxJsonFileBytes)
        throw ConfigError("", "'" + path + "' is " + std::to_string(size) + " bytes: more than the " + std::to_string(kMaxJsonFileBytes >> 20) + " MiB a JSON file here may hold");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw ConfigError("", "cannot open '" + path + "'");
    std::ostringstream text;
    try {
        text << in.rdbuf();
    } catch (const std::ios_base::failure& e) {
        throw ConfigError("", "cannot read '" + path + "': " + e.what());
    }
    if (in.bad()) throw ConfigError("", "cannot read '" + path + "'");
    // Nesting at most kMaxJsonDepth, no key twice: the error names the key and the file.
    return parse_json_bounded(text.str(), path);
}

namespace {
// Stored, listed and printed with every run: long enough for any real name, short enough
// that a list of runs stays small.
constexpr std::size_t kMaxNameChars = 200;
constexpr std::size_t kMaxDescriptionChars = 10000;

std::size_t utf8_chars(const std::string& s) {
    std::size_t n = 0;
    for (const char c : s) n += (static_cast<unsigned char>(c) & 0xC0) != 0x80;
    return n;
}

std::string bounded(std::string v, const std::string& key, std::size_t max_chars) {
    if (const auto n = utf8_chars(v); n > max_chars)
        throw ConfigError(key, "too long: " + std::to_string(n) + " characters (at most " + std::to_string(max_chars) + ")");
    return v;
}
}  // namespace

json resolve_json_ref(const json& j, const std::string& base_dir, std::string* file_out) {
    if (file_out) file_out->clear();
    if (!j.is_string()) return j;
    fs::path p(j.get<std::string>());
    if (p.is_relative()) p = fs::path(base_dir) / p;
    if (file_out) *file_out = p.string();
    return load_json_file(p.string());
}

EncoderProfile load_encoder(const std::string& path) { return encoder_from_json(load_json_file(path), "encoder"); }

InterfaceProfile load_interface(const std::string& path) {
    const json j = load_json_file(path);  // its faults name the file already
    try {
        return interface_from_json(j, "interface");
    } catch (const ConfigError& e) {
        throw ConfigError(e.field().empty() ? "interface" : e.field(), e.message() + " (in " + path + ")");
    }
}

const KeyTable& scenario_keys() {
    static const Scenario d;
    static const KeyTable t({
        key_string("name", d.name, "the scenario's name (reports, history)", false),
        key_string("description", "", "free text", false),
        key_number("sample_rate_hz", "Hz", d.sample_rate_hz, 1.0, 1e10, "samples per second of the stream"),
        key_number("duration_s", "s", nullptr, 1e-9, 1e7, "length of the run (required)"),
        key_number("settle_s", "s", d.settle_s, 0.0, 1e7, "seconds at the start excluded from scoring"),
        key_integer("seed", "", d.seed, 0, 9007199254740992.0, "noise seed"),
        key_number("t0_s", "s", d.t0_s, -1e9, 1e9, "time of sample 0"),
        key_string("dut", "", "DUT serial for the history (default: the device's board id)", false),
        key_string("dut_part", "", "DUT part number (provenance)", false),
        key_integer("scoring.max_harmonic", "", d.scoring.max_harmonic, 1, 64, "error harmonics fitted: 1x to this", false),
        key_integer("scoring.min_scored_samples", "", d.scoring.min_scored_samples, 1, 9007199254740992.0, "evidence: at least this many scored samples", false),
        key_number("scoring.min_scored_cycles", "", d.scoring.min_scored_cycles, 0.0, 1e12, "evidence: electrical cycles of truth under the scored samples", false),
        key_number("scoring.min_valid_fraction", "", d.scoring.min_valid_fraction, 0.0, 1.0, "evidence: valid share of the samples after the settle time", false),
        key_integer("scoring.max_slipped_samples", "", d.scoring.max_slipped_samples, 0, 9007199254740992.0, "evidence: scored samples off by more than pi at most", false),
        key_boolean("scoring.self_reference", d.scoring.self_reference,
                    "also measure each estimator's error without truth, against a reference built from its own output (on for a capture without truth)", false),
        key_string("calibrate.lane", nullptr, "calibrate, apply, re-run: the label of the atan2 lane a correction is computed for (docs/calibration.md)", false),
        key_integer("calibrate.table_size", "", static_cast<double>(CalibrateSpec{}.table_size), 2, kMaxRunTableSize, "entries of the correction table over an electrical period (the report holds them)", false),
        key_integer("calibrate.harmonics", "", CalibrateSpec{}.harmonics, 1, 256, "harmonic orders of the correction the table is built from", false),
        key_boolean("calibrate.lissajous", CalibrateSpec{}.lissajous, "identify offsets, gains and quadrature (ellipse fit) before the table", false),
        key_number("calibrate.min_cycles", "", CalibrateSpec{}.min_cycles, 1.0, 1e12, "electrical cycles the error record needs for a correction", false),
        key_choice("calibrate.error_source", CalibrateSpec{}.error_source, {"auto", "truth", "self_reference"},
                   "the error the correction is computed from: truth where the capture has it (auto), truth only, or the self-referenced error", false),
        key_integer("calibrate.verify.seed", "", nullptr, 0, 9007199254740992.0, "the after pass's noise seed (default: the scenario's seed + 1)", false),
        key_string("calibrate.verify.device", "", "the after pass's device URI (default: the scenario's; a capture: device needs another capture)", false),
    });
    return t;
}

const KeyTable& limit_keys() {
    static const KeyTable t({
        key_string("estimator", "*", "the estimator's label, \"*\" for every one, \"run\" for a run-level metric", false),
        key_string("metric", nullptr, "a metric's name (\"metrics\")", false),
        key_number("max", "", nullptr, -kInf, kInf, "FAIL above (the metric's unit)"),
        key_number("min", "", nullptr, -kInf, kInf, "FAIL below (the metric's unit)"),
        key_number("marginal_fraction", "", 0.0, 0.0, 1.0, "MARGINAL within this fraction of |limit| on the passing side"),
    });
    return t;
}

Scenario scenario_from_json(const json& j, const std::string& base_dir) {
    JsonReader r(j, "");
    Scenario s;
    const KeyTable& k = scenario_keys();
    s.name = bounded(k.string(r, "name"), "name", kMaxNameChars);
    s.description = bounded(k.string(r, "description"), "description", kMaxDescriptionChars);
    // A profile given inline or as a file relative to the scenario: a fault inside a file names it.
    auto referenced = [&](const char* field, const char* what, auto parse) {
        const json& ref = r.raw(field);
        if (!ref.is_string() && !ref.is_object()) throw ConfigError(field, std::string("expected ") + what + " object or a file name");
        std::string file;
        try {
            return parse(resolve_json_ref(ref, base_dir, &file), field);
        } catch (const ConfigError& e) {
            if (file.empty()) throw;
            throw ConfigError(e.field().empty() ? field : e.field(), e.message() + " (in " + file + ")");
        }
    };
    // A capture replayed moves as it was captured and has its own rate and length: its run
    // takes them from the capture (plan_run), so a capture: device's scenario may leave out
    // "motion" (or leave it half filled in, a form's: it is not read), "sample_rate_hz",
    // "duration_s" and "encoder" (then the capture's own, else none: no bounds, no arcsec).
    const bool replay = r.has("device") && r.raw("device").is_string() && r.raw("device").get<std::string>().rfind("capture:", 0) == 0;
    if (replay && (!r.has("encoder") || r.raw("encoder").is_null())) s.encoder_known = false;
    else s.encoder = referenced("encoder", "a profile", encoder_from_json);
    if (r.has("interface")) s.interface = referenced("interface", "an interface profile", interface_from_json);
    s.length_from_capture = replay && (!r.has("sample_rate_hz") || !r.has("duration_s"));
    s.sample_rate_hz = replay && !r.has("sample_rate_hz") ? 0.0 : k.number(r, "sample_rate_hz");
    s.duration_s = replay && !r.has("duration_s") ? 0.0 : k.number(r, "duration_s");
    s.t0_s = k.number(r, "t0_s");
    s.seed = static_cast<std::uint64_t>(k.integer(r, "seed"));
    if (!replay) s.motion = motion_from_json(r.raw("motion"), base_dir, s.encoder.lines_per_rev, "motion");
    else if (r.has("motion")) r.raw("motion");
    s.motion_unread = replay;
    if (!s.length_from_capture && s.samples() < 1) throw ConfigError("duration_s", "gives no samples at this sample rate");
    if (r.has("device") && r.raw("device").is_object()) {
        JsonReader dr = r.object("device");
        Scenario::Instruments ins;
        ins.output = dr.string("output");
        ins.input = dr.string("input");
        ins.dut = dr.string("dut", "");
        dr.finish();
        s.instruments = ins;
        s.device.clear();
    } else if (r.has("device") && !r.raw("device").is_string()) {
        throw ConfigError("device", "expected a device URI or {\"output\": URI, \"input\": URI}");
    } else {
        s.device = r.string("device", s.device);
    }
    s.settle_s = k.number(r, "settle_s");
    s.dut = bounded(k.string(r, "dut"), "dut", kMaxNameChars);
    s.dut_part = bounded(k.string(r, "dut_part"), "dut_part", kMaxNameChars);
    if (r.has("scoring")) {
        JsonReader sr = r.object("scoring");
        s.scoring.max_harmonic = static_cast<int>(k.integer(sr, "scoring.max_harmonic"));
        s.scoring.min_scored_samples = static_cast<std::uint64_t>(k.integer(sr, "scoring.min_scored_samples"));
        s.scoring.min_scored_cycles = k.number(sr, "scoring.min_scored_cycles");
        s.scoring.min_valid_fraction = k.number(sr, "scoring.min_valid_fraction");
        s.scoring.max_slipped_samples = static_cast<std::uint64_t>(k.integer(sr, "scoring.max_slipped_samples"));
        s.scoring.self_reference = k.boolean(sr, "scoring.self_reference");
        sr.finish();
    }
    if (r.has("calibrate")) {
        JsonReader cr = r.object("calibrate");
        CalibrateSpec c;
        c.table_size_given = cr.has("table_size");
        c.table_size = static_cast<std::size_t>(k.integer(cr, "calibrate.table_size"));
        c.harmonics = static_cast<int>(k.integer(cr, "calibrate.harmonics"));
        c.lissajous = k.boolean(cr, "calibrate.lissajous");
        c.min_cycles = k.number(cr, "calibrate.min_cycles");
        c.error_source = k.choice(cr, "calibrate.error_source");
        if (cr.has("verify")) {
            JsonReader vr = cr.object("verify");
            if (vr.has("seed")) c.verify.seed = static_cast<std::uint64_t>(k.integer(vr, "calibrate.verify.seed"));
            c.verify.device = k.string(vr, "calibrate.verify.device");
            if (vr.has("motion")) c.verify.motion = motion_from_json(vr.raw("motion"), base_dir, s.encoder.lines_per_rev, "calibrate.verify.motion");
            vr.finish();
        }
        c.lane = k.string(cr, "calibrate.lane");  // after the values: a value out of range is named first
        cr.finish();
        s.calibrate = std::move(c);
    }
    if (r.has("estimators")) {
        const json& arr = r.raw("estimators");
        if (!arr.is_array()) throw ConfigError("estimators", "expected an array of {name, params}");
        for (std::size_t i = 0; i < arr.size(); ++i) {
            const std::string path = "estimators[" + std::to_string(i) + "]";
            JsonReader er(arr[i], path);
            EstimatorSpec e;
            e.name = er.string("name");
            e.label = bounded(er.string("label", e.name), path + ".label", kMaxNameChars);
            // Limits and reports name lanes by label: "run" is the run's own lane, "*" every
            // lane, "dut" a board's own position; an empty label names nothing.
            if (e.label.empty() || e.label == "run" || e.label == "*" || e.label == "dut")
                throw ConfigError(path + ".label", "'" + e.label + "' is reserved (\"run\": the run's own figures, \"*\": every estimator, "
                                                   "\"dut\": a board's own position; an empty label names nothing): give another label");
            if (er.has("params")) e.params = er.raw("params");
            // A correction file is found beside the scenario, as its encoder is (not in the
            // current folder: a scenario run from elsewhere, or on the service, read another file).
            if (e.params.is_object() && e.params.contains("correction") && e.params["correction"].is_string() && !base_dir.empty()) {
                const fs::path cp(e.params["correction"].get<std::string>());
                if (cp.is_relative() && !cp.empty()) e.params["correction"] = (fs::path(base_dir) / cp).lexically_normal().string();
            }
            if (er.has("encoder")) e.encoder = encoder_from_json(resolve_json_ref(er.raw("encoder"), base_dir), path + ".encoder");
            er.finish();
            for (const auto& other : s.estimators)
                if (other.label == e.label) throw ConfigError(path + ".label", "duplicate label '" + e.label + "' (give each a distinct label)");
            s.estimators.push_back(std::move(e));
        }
    }
    if (r.has("limits")) {
        const json& arr = r.raw("limits");
        if (!arr.is_array()) throw ConfigError("limits", "expected an array of {estimator, metric, max|min}");
        for (std::size_t i = 0; i < arr.size(); ++i) {
            const std::string path = "limits[" + std::to_string(i) + "]";
            JsonReader lr(arr[i], path);
            Limit l;
            const KeyTable& lk = limit_keys();
            l.estimator = lk.string(lr, "estimator");
            l.metric = lk.string(lr, "metric");
            l.max = lk.optional_number(lr, "max");
            l.min = lk.optional_number(lr, "min");
            l.marginal_fraction = lk.number(lr, "marginal_fraction");
            lr.finish();
            if (!l.max && !l.min) throw ConfigError(path, "needs max or min");
            if (l.max && l.min && *l.min > *l.max)
                throw ConfigError(path + ".min", "min " + std::to_string(*l.min) + " is above max " + std::to_string(*l.max) + ": no value could pass");
            s.limits.push_back(std::move(l));
        }
    }
    r.finish();
    return s;
}

Scenario load_scenario(const std::string& path) {
    json j = load_json_file(path);
    try {
        return scenario_from_json(j, fs::path(path).parent_path().string());
    } catch (const ConfigError& e) {
        // Every scenario error names its file (an encoder file's errors name theirs already).
        if (e.message().find(" (in ") != std::string::npos) throw;
        throw ConfigError(e.field(), e.message() + " (in " + path + ")");
    }
}

void to_json(json& j, const Scenario& s) {
    j = json{{"name", s.name}, {"encoder", s.encoder_known ? json(s.encoder) : json()}, {"motion", s.motion},
             {"sample_rate_hz", s.sample_rate_hz}, {"duration_s", s.duration_s},
             {"t0_s", s.t0_s}, {"seed", s.seed}};
    if (!s.description.empty()) j["description"] = s.description;
    if (s.interface) j["interface"] = *s.interface;
    if (s.instruments) {
        j["device"] = {{"output", s.instruments->output}, {"input", s.instruments->input}};
        if (!s.instruments->dut.empty()) j["device"]["dut"] = s.instruments->dut;
    } else {
        j["device"] = s.device;
    }
    j["settle_s"] = s.settle_s;
    if (!s.dut.empty()) j["dut"] = s.dut;
    if (!s.dut_part.empty()) j["dut_part"] = s.dut_part;
    j["scoring"] = {{"max_harmonic", s.scoring.max_harmonic}, {"min_scored_samples", s.scoring.min_scored_samples},
                    {"min_scored_cycles", s.scoring.min_scored_cycles}, {"min_valid_fraction", s.scoring.min_valid_fraction},
                    {"max_slipped_samples", s.scoring.max_slipped_samples}, {"self_reference", s.scoring.self_reference}};
    auto est = json::array();
    for (const auto& e : s.estimators) {
        json x{{"name", e.name}, {"label", e.label}, {"params", e.params}};
        if (e.encoder) x["encoder"] = *e.encoder;
        est.push_back(x);
    }
    j["estimators"] = est;
    auto lim = json::array();
    for (const auto& l : s.limits) {
        json x{{"estimator", l.estimator}, {"metric", l.metric}, {"marginal_fraction", l.marginal_fraction}};
        if (l.max) x["max"] = *l.max;
        if (l.min) x["min"] = *l.min;
        lim.push_back(x);
    }
    j["limits"] = lim;
    if (s.calibrate) {
        const CalibrateSpec& c = *s.calibrate;
        json v = json::object();
        if (c.verify.seed) v["seed"] = *c.verify.seed;
        if (c.verify.motion) v["motion"] = *c.verify.motion;
        if (!c.verify.device.empty()) v["device"] = c.verify.device;
        j["calibrate"] = {{"lane", c.lane}, {"harmonics", c.harmonics}, {"lissajous", c.lissajous}, {"min_cycles", c.min_cycles}, {"error_source", c.error_source}, {"verify", v}};
        if (c.table_size_given) j["calibrate"]["table_size"] = c.table_size;  // else the board's, or the default, when planned
    }
}

}  // namespace fringe
