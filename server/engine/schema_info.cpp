#include "server/engine/schema_info.hpp"

#include "server/engine/limits.hpp"
#include "signal_gen/base/params.hpp"

namespace fringe {

using nlohmann::json;

namespace {

ParamInfo num(std::string name, std::string unit, json def, double lo, double hi, std::string desc) {
    ParamInfo p;
    p.name = std::move(name);
    p.unit = std::move(unit);
    p.type = ParamType::Number;
    p.default_value = std::move(def);
    p.min = lo;
    p.max = hi;
    p.description = std::move(desc);
    return p;
}
ParamInfo integer(std::string name, std::string unit, json def, double lo, double hi, std::string desc) {
    ParamInfo p = num(std::move(name), std::move(unit), std::move(def), lo, hi, std::move(desc));
    p.type = ParamType::Integer;
    return p;
}
ParamInfo choice(std::string name, std::string def, std::vector<std::string> options, std::string desc) {
    ParamInfo p;
    p.name = std::move(name);
    p.type = ParamType::Choice;
    p.default_value = std::move(def);
    p.options = std::move(options);
    p.description = std::move(desc);
    return p;
}

constexpr double kMaxV = 1e6, kMaxA = 1e9;  // motion.cpp's bounds

}  // namespace

json scenario_schema() {
    const std::vector<ParamInfo> scenario = {
        num("sample_rate_hz", "Hz", 100000, 1.0, 1e10, "samples per second of the stream"),
        num("duration_s", "s", nullptr, 1e-9, 1e7, "length of the run (required)"),
        num("settle_s", "s", 0.1, 0.0, 1e7, "seconds at the start excluded from scoring"),
        integer("seed", "", 1, 0, 9007199254740992.0, "noise seed"),
        num("t0_s", "s", 0.0, -1e9, 1e9, "time of sample 0"),
    };
    const std::vector<ParamInfo> encoder = {
        choice("model", "diffraction", {"diffraction", "ideal"}, "diffraction: the paper's closed form; ideal: quadrature sinusoids"),
        integer("lines_per_rev", "lines", 1024, 1, 1 << 24, "grating lines per revolution"),
        num("vmax_v", "V", 1.0, 1e-6, 1e3, "amplitude (ideal) or source/detector scale (diffraction)"),
        num("radius_cm", "cm", 2.5, 1e-3, 1e3, "nominal track radius"),
        num("noise.sigma_add_v", "V", 0.0, 0.0, 100.0, "additive white noise per channel, rms"),
        num("noise.sigma_gain", "", 0.0, 0.0, 0.5, "common multiplicative white noise, relative rms"),
        num("lissajous.gain_mismatch", "", 0.0, -1.0, 1.0, "gain mismatch eps: gains 1 + eps/2 (sin), 1 - eps/2 (cos)"),
        num("lissajous.offset_sin_v", "V", 0.0, -100.0, 100.0, "offset of the sin channel"),
        num("lissajous.offset_cos_v", "V", 0.0, -100.0, 100.0, "offset of the cos channel"),
        num("lissajous.quadrature_error_rad", "rad", 0.0, -1.5, 1.5, "quadrature error: cos channel at theta + delta"),
        integer("adc.bits", "bit", 0, 0, 32, "the encoder's own converter (0: none; the device digitises)"),
        num("adc.min_v", "V", -1.25, -1e3, 1e3, "the encoder converter's lower rail"),
        num("adc.max_v", "V", 1.25, -1e3, 1e3, "the encoder converter's upper rail"),
    };
    const double v_max = kMaxV;
    auto velocity = [&](json def, const char* what) { return num("velocity_rad_s", "rad/s", std::move(def), -v_max, v_max, what); };
    json motion = json::array({
        {{"kind", "constant"}, {"summary", "constant speed"},
         {"params", std::vector<ParamInfo>{velocity(nullptr, "shaft speed (or electrical_freq_hz)"),
                                           num("electrical_freq_hz", "Hz", nullptr, -1e9, 1e9, "signal frequency instead of velocity_rad_s"),
                                           num("phi0_rad", "rad", 0.0, -1e6, 1e6, "shaft angle at t = 0")}}},
        {{"kind", "ramp"}, {"summary", "constant acceleration"},
         {"params", std::vector<ParamInfo>{velocity(0.0, "initial shaft speed"), num("accel_rad_s2", "rad/s^2", nullptr, -kMaxA, kMaxA, "acceleration"),
                                           num("phi0_rad", "rad", 0.0, -1e6, 1e6, "shaft angle at t = 0")}}},
        {{"kind", "trapezoid"}, {"summary", "rest, accelerate, cruise, decelerate, rest"},
         {"params", std::vector<ParamInfo>{velocity(nullptr, "cruise speed"), num("accel_rad_s2", "rad/s^2", nullptr, 1e-9, kMaxA, "acceleration"),
                                           num("start_s", "s", 0.0, 0.0, 1e6, "rest before the move"), num("cruise_s", "s", 0.0, 0.0, 1e6, "time at cruise speed"),
                                           num("phi0_rad", "rad", 0.0, -1e6, 1e6, "shaft angle at t = 0")}}},
        {{"kind", "sine"}, {"summary", "oscillation (with reversals) on an optional drift"},
         {"params", std::vector<ParamInfo>{num("amplitude_rad", "rad", nullptr, 0.0, 1e6, "oscillation amplitude (shaft)"),
                                           num("freq_hz", "Hz", nullptr, 0.0, 1e6, "oscillation frequency"), num("phase_rad", "rad", 0.0, -1e3, 1e3, "phase"),
                                           velocity(0.0, "drift speed"), num("phi0_rad", "rad", 0.0, -1e6, 1e6, "shaft angle at t = 0")}}},
        {{"kind", "steps"}, {"summary", "quasi-static steps"},
         {"params", std::vector<ParamInfo>{num("step_rad", "rad", nullptr, -1e3, 1e3, "step (shaft)"), num("dwell_s", "s", nullptr, 1e-9, 1e6, "time per step"),
                                           num("phi0_rad", "rad", 0.0, -1e6, 1e6, "shaft angle at t = 0")}}},
    });
    const std::vector<ParamInfo> limit = {
        num("max", "", nullptr, -kInf, kInf, "FAIL above (the metric's unit)"),
        num("min", "", nullptr, -kInf, kInf, "FAIL below (the metric's unit)"),
        num("marginal_fraction", "", 0.0, 0.0, 1.0, "MARGINAL within this fraction of |limit| on the passing side"),
    };
    return {{"scenario", scenario}, {"encoder", encoder}, {"motion", motion}, {"limit", limit}, {"metrics", metric_table_json()}};
}

}  // namespace fringe
