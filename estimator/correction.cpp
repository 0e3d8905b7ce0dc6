#include "correction.hpp"

#include "common.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/json_bounded.hpp"

#include <cmath>
#include <filesystem>
#include <system_error>
#include <fstream>
#include <iterator>

namespace fringe::est {

namespace {

constexpr double kTwoPiC = 6.283185307179586476925;

std::vector<double> number_array(const nlohmann::json& j, const char* key, const std::string& path) {
    std::vector<double> v;
    if (!j.contains(key)) return v;
    const auto& a = j.at(key);
    if (!a.is_array()) throw ConfigError(path + "." + key, "must be an array of numbers");
    for (const auto& x : a) {
        if (!x.is_number() || !std::isfinite(x.get<double>())) throw ConfigError(path + "." + key, "must be an array of finite numbers");
        v.push_back(x.get<double>());
    }
    return v;
}

// What a correction file may hold (fringe calibrate writes at most these).
constexpr std::size_t kMaxTableEntries = std::size_t{1} << 20;
constexpr std::size_t kMaxHarmonics = 256;
constexpr double kMinAmplitudeV = 1e-6, kMaxSignalV = 1000;

double number(const nlohmann::json& j, const char* key, const std::string& path) {
    if (!j.contains(key) || !j.at(key).is_number() || !std::isfinite(j.at(key).get<double>()))
        throw ConfigError(path + "." + key, "must be a finite number");
    return j.at(key).get<double>();
}

}  // namespace

double Correction::harmonic_value(double phi) const {
    double v = 0;
    for (std::size_t k = 0; k < cos_k.size(); ++k) {
        const double a = static_cast<double>(k + 1) * phi;
        v += cos_k[k] * std::cos(a) + sin_k[k] * std::sin(a);
    }
    return v;
}

void Correction::tabulate(std::size_t n) {
    table.assign(n, 0.0);
    for (std::size_t i = 0; i < n; ++i) table[i] = harmonic_value(kTwoPiC * static_cast<double>(i) / static_cast<double>(n));
}

nlohmann::json Correction::to_json() const {
    nlohmann::json j{{"schema", "fringe.correction"},
                     {"schema_version", 1},
                     {"sign", "subtracted: theta_corrected = phi - offset_rad - c(phi), c = estimate minus truth at the angle phi read"},
                     {"interpolation", "linear between entries; entry i at 2*pi*i/N; entry N = entry 0"}};
    if (has_lissajous)
        j["lissajous"] = {{"offset_sin_v", offset_sin_v},       {"offset_cos_v", offset_cos_v},
                          {"amplitude_sin_v", amplitude_sin_v}, {"amplitude_cos_v", amplitude_cos_v},
                          {"gain_ratio_sin_to_cos", amplitude_sin_v / amplitude_cos_v},
                          {"quadrature_error_rad", quadrature_error_rad}};
    nlohmann::json h = nlohmann::json::array();
    for (std::size_t k = 0; k < cos_k.size(); ++k) h.push_back({{"order", k + 1}, {"cos_rad", cos_k[k]}, {"sin_rad", sin_k[k]}});
    j["harmonics"] = std::move(h);
    j["table_rad"] = table;
    j["offset_rad"] = offset_rad;
    return j;
}

Correction Correction::from_json(const nlohmann::json& j) {
    const std::string p = "correction";
    if (!j.is_object()) throw ConfigError(p, "must be a JSON object");
    if (!j.contains("schema") || !j["schema"].is_string() || j["schema"] != "fringe.correction") throw ConfigError(p + ".schema", "must be \"fringe.correction\"");
    if (!j.contains("schema_version") || !j["schema_version"].is_number_integer() || j["schema_version"] != 1)
        throw ConfigError(p + ".schema_version", "must be 1 (this fringe reads version 1 of the correction file)");
    // Every key is one this version writes: a misspelt one (tabel_rad) was silently ignored.
    auto only = [](const nlohmann::json& o, std::initializer_list<const char*> keys, const std::string& at) {
        for (auto it = o.begin(); it != o.end(); ++it) {
            bool known = false;
            for (const char* k : keys) known |= it.key() == k;
            if (!known) throw ConfigError(at + "." + it.key(), "unknown key");
        }
    };
    only(j, {"schema", "schema_version", "sign", "interpolation", "calibrated_from", "lissajous", "harmonics", "table_rad", "offset_rad"}, p);
    Correction c;
    if (j.contains("lissajous")) {
        const auto& l = j.at("lissajous");
        const std::string lp = p + ".lissajous";
        if (!l.is_object()) throw ConfigError(lp, "must be an object");
        only(l, {"offset_sin_v", "offset_cos_v", "amplitude_sin_v", "amplitude_cos_v", "gain_ratio_sin_to_cos", "quadrature_error_rad"}, lp);
        c.has_lissajous = true;
        c.offset_sin_v = number(l, "offset_sin_v", lp);
        c.offset_cos_v = number(l, "offset_cos_v", lp);
        c.amplitude_sin_v = number(l, "amplitude_sin_v", lp);
        c.amplitude_cos_v = number(l, "amplitude_cos_v", lp);
        c.quadrature_error_rad = number(l, "quadrature_error_rad", lp);
        // A signal's amplitude and offset in volts: 1e-300 V or 1e300 V made every angle noise.
        for (const auto& [key, v] : {std::pair{"amplitude_sin_v", c.amplitude_sin_v}, std::pair{"amplitude_cos_v", c.amplitude_cos_v}})
            if (!(v >= kMinAmplitudeV && v <= kMaxSignalV))
                throw ConfigError(lp + "." + key, "must be within [1e-6, 1000] V (a signal's amplitude)");
        for (const auto& [key, v] : {std::pair{"offset_sin_v", c.offset_sin_v}, std::pair{"offset_cos_v", c.offset_cos_v}})
            if (!(std::fabs(v) <= kMaxSignalV)) throw ConfigError(lp + "." + key, "must be within [-1000, 1000] V");
        if (!(std::fabs(c.quadrature_error_rad) < kTwoPiC / 4)) throw ConfigError(lp + ".quadrature_error_rad", "must be within (-pi/2, pi/2)");
    }
    if (j.contains("harmonics")) {
        const auto& h = j.at("harmonics");
        if (!h.is_array()) throw ConfigError(p + ".harmonics", "must be an array");
        for (std::size_t k = 0; k < h.size(); ++k) {
            const std::string hp = p + ".harmonics[" + std::to_string(k) + "]";
            if (k >= kMaxHarmonics) throw ConfigError(p + ".harmonics", "at most " + std::to_string(kMaxHarmonics) + " orders");
            if (!h[k].is_object() || !h[k].contains("order") || !h[k]["order"].is_number_integer() || h[k]["order"] != k + 1)
                throw ConfigError(hp + ".order", "orders must be the integers 1, 2, 3, ... in turn");
            only(h[k], {"order", "cos_rad", "sin_rad"}, hp);
            c.cos_k.push_back(number(h[k], "cos_rad", hp));
            c.sin_k.push_back(number(h[k], "sin_rad", hp));
        }
    }
    c.table = number_array(j, "table_rad", p);
    if (j.contains("table_rad") && (c.table.size() < 2 || c.table.size() > kMaxTableEntries))
        throw ConfigError(p + ".table_rad", std::to_string(c.table.size()) + " entries: a table has 2 to " + std::to_string(kMaxTableEntries) +
                                                " (leave table_rad out to apply the harmonics)");
    if (c.table.empty() && c.cos_k.empty() && !c.has_lissajous && !j.contains("offset_rad"))
        throw ConfigError(p, "no correction in it: no table_rad, harmonics, lissajous or offset_rad");
    if (j.contains("offset_rad")) c.offset_rad = number(j, "offset_rad", p);
    // An interpolator's error is a fraction of a period: a correction of more than half a period
    // at an angle (or an offset of more than a whole one) is not one; 1e300 in a table made
    // the estimate not finite, and offset_rad 1e308 a constant output that scored as no error.
    constexpr double kHalfPeriodRad = kTwoPiC / 2;
    for (std::size_t i = 0; i < c.table.size(); ++i)
        if (!(std::fabs(c.table[i]) <= kHalfPeriodRad))
            throw ConfigError(p + ".table_rad[" + std::to_string(i) + "]", "must be within [-pi, pi] rad (a correction is a fraction of a period)");
    double sum_abs_rad = 0;
    for (std::size_t k = 0; k < c.cos_k.size(); ++k) sum_abs_rad += std::fabs(c.cos_k[k]) + std::fabs(c.sin_k[k]);
    if (!(sum_abs_rad <= kHalfPeriodRad))
        throw ConfigError(p + ".harmonics", "the harmonics' amplitudes add up to more than pi rad (a correction is a fraction of a period)");
    if (!(std::fabs(c.offset_rad) <= kTwoPiC)) throw ConfigError(p + ".offset_rad", "must be within [-2 pi, 2 pi] rad");
    return c;
}

fringe::ParamInfo correction_param() {
    return {"correction", "", ParamType::String, nullptr, -kInf, kInf, {},
            "correction file (fringe calibrate -o; docs/calibration.md): its Lissajous stage replaces the nominal calibration "
            "(not with the calibration parameters), its offset and table are subtracted from the angle"};
}

std::unique_ptr<Correction> correction_from_params(const fringe::Params& p, Calibration& cal) {
    if (!p.json().contains("correction") || p.json().at("correction").is_null()) return nullptr;
    std::unique_ptr<Correction> c;
    try {
        c = std::make_unique<Correction>(Correction::load(p.string("correction")));
    } catch (const ConfigError& e) {
        throw e.prefixed("params");
    }
    if (c->has_lissajous) {
        for (const char* k : {"offset_sin_v", "offset_cos_v", "amplitude_sin_v", "amplitude_cos_v", "quadrature_error_rad"})
            if (p.optional_number(k))
                throw ConfigError(std::string("params.") + k, "the correction file has a Lissajous stage: give one or the other");
        c->lissajous_into(cal);
    }
    return c;
}

void Correction::lissajous_into(Calibration& cal) const {
    cal.offset_sin_v = offset_sin_v;
    cal.offset_cos_v = offset_cos_v;
    cal.amplitude_sin_v = amplitude_sin_v;
    cal.amplitude_cos_v = amplitude_cos_v;
    cal.quadrature_error_rad = quadrature_error_rad;
    cal.prepare();
}

void Correction::lissajous_from(const Calibration& cal) {
    has_lissajous = true;
    offset_sin_v = cal.offset_sin_v;
    offset_cos_v = cal.offset_cos_v;
    amplitude_sin_v = cal.amplitude_sin_v;
    amplitude_cos_v = cal.amplitude_cos_v;
    quadrature_error_rad = cal.quadrature_error_rad;
}

Correction Correction::load(const std::string& path) {
    // A regular file only: a folder gave the stream library's own words, a FIFO waited forever.
    std::error_code ec;
    const auto st = std::filesystem::status(path, ec);
    if (ec && ec != std::errc::no_such_file_or_directory) throw ConfigError("correction", "cannot open " + path + " (" + ec.message() + ")");  // a link loop
    if (!std::filesystem::exists(st)) throw ConfigError("correction", "cannot open " + path + " (no such file)");
    if (!std::filesystem::is_regular_file(st)) throw ConfigError("correction", path + " is not a regular file");
    // A table of 2^20 entries is about 25 MB of JSON; a larger file is not one fringe wrote.
    if (const auto size = std::filesystem::file_size(path, ec); !ec && size > (std::uintmax_t{64} << 20))
        throw ConfigError("correction", path + " is " + std::to_string(size >> 20) + " MiB: a correction file is at most 64 MiB");
    std::ifstream f(path);
    if (!f) throw ConfigError("correction", "cannot open " + path);
    const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    nlohmann::json j;
    // The whole file (trailing text after the object is an error too), bounded in depth, and a
    // key given twice refused (the last one silently won: a table given twice took the second).
    try {
        j = parse_json_bounded(text, path);
    } catch (const ConfigError& e) {
        throw e.prefixed("correction");
    }
    return from_json(j);
}

}  // namespace fringe::est
