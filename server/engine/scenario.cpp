#include "server/engine/scenario.hpp"

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

Scenario scenario_from_json(const json& j, const std::string& base_dir) {
    JsonReader r(j, "");
    Scenario s;
    s.name = bounded(r.string("name", s.name), "name", kMaxNameChars);
    s.description = bounded(r.string("description", ""), "description", kMaxDescriptionChars);
    const json& enc = r.raw("encoder");
    if (!enc.is_string() && !enc.is_object()) throw ConfigError("encoder", "expected a profile object or a file name");
    std::string file;
    try {
        s.encoder = encoder_from_json(resolve_json_ref(enc, base_dir, &file), "encoder");
    } catch (const ConfigError& e) {
        if (file.empty()) throw;
        throw ConfigError(e.field().empty() ? "encoder" : e.field(), std::string(e.what()) + " (in " + file + ")");
    }
    s.sample_rate_hz = r.number("sample_rate_hz", s.sample_rate_hz, 1.0, 1e10);
    s.duration_s = r.number("duration_s", 1e-9, 1e7);
    s.t0_s = r.number("t0_s", 0.0, -1e9, 1e9);
    s.seed = static_cast<std::uint64_t>(r.integer("seed", 1, 0, (1LL << 53)));
    s.motion = motion_from_json(r.raw("motion"), base_dir, s.encoder.lines_per_rev, "motion");
    if (s.samples() < 1) throw ConfigError("duration_s", "gives no samples at this sample rate");
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
    s.settle_s = r.number("settle_s", s.settle_s, 0.0, 1e7);
    s.dut = bounded(r.string("dut", ""), "dut", kMaxNameChars);
    s.dut_part = bounded(r.string("dut_part", ""), "dut_part", kMaxNameChars);
    if (r.has("scoring")) {
        JsonReader sr = r.object("scoring");
        s.scoring.max_harmonic = static_cast<int>(sr.integer("max_harmonic", s.scoring.max_harmonic, 1, 64));
        s.scoring.min_scored_samples = static_cast<std::uint64_t>(sr.integer("min_scored_samples", 1000, 1, 1LL << 53));
        s.scoring.min_scored_cycles = sr.number("min_scored_cycles", s.scoring.min_scored_cycles, 0.0, 1e12);
        s.scoring.min_valid_fraction = sr.number("min_valid_fraction", s.scoring.min_valid_fraction, 0.0, 1.0);
        s.scoring.max_slipped_samples = static_cast<std::uint64_t>(sr.integer("max_slipped_samples", 0, 0, 1LL << 53));
        sr.finish();
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
            if (er.has("params")) e.params = er.raw("params");
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
            l.estimator = lr.string("estimator", "*");
            l.metric = lr.string("metric");
            l.max = lr.optional_number("max", -kInf, kInf);
            l.min = lr.optional_number("min", -kInf, kInf);
            l.marginal_fraction = lr.number("marginal_fraction", 0.0, 0.0, 1.0);
            lr.finish();
            if (!l.max && !l.min) throw ConfigError(path, "needs max or min");
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
                    {"max_slipped_samples", s.scoring.max_slipped_samples}};
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
}

}  // namespace fringe
