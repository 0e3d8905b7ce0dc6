#include "encoder.hpp"
#include "keys.hpp"

#include "signal_gen/base/config.hpp"
#include "fastmath.hpp"
#include "optics.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>

namespace fringe {

using nlohmann::json;

const KeyTable& encoder_keys() {
    static const EncoderProfile d;
    static const KeyTable t({
        key_string("name", d.name, "the profile's name (reports, history)", false),
        key_string("description", "", "free text", false),
        key_choice("model", "diffraction", {"diffraction", "ideal"}, "diffraction: the paper's closed form; ideal: quadrature sinusoids"),
        key_integer("lines_per_rev", "lines", d.lines_per_rev, 1, 1 << 24, "grating lines per revolution"),
        key_number("vmax_v", "V", d.vmax_v, 1e-6, 1e3, "amplitude (ideal) or source/detector scale (diffraction)"),
        key_number("radius_cm", "cm", d.radius_cm, 1e-3, 1e3, "nominal track radius"),
        key_number("optics.aperture_w_rad", "rad", d.aperture_w_rad, 1e-6, kTwoPi, "detector aperture in electrical rad (model diffraction only)", false),
        key_number("optics.kappa_ref", "", d.kappa_ref, 1e-3, 50.0, "kappa at gap_ref_cm and the track radius (model diffraction only)", false),
        key_number("optics.gap_ref_cm", "cm", d.gap_ref_cm, 1e-6, 1e3, "the gap kappa_ref is given at (model diffraction only)", false),
        key_number("geometry.gap_d1_cm", "cm", nullptr, 1e-6, 1e3, "gap at phi + gap_phase = 0 (default: optics.gap_ref_cm)", false),
        key_number("geometry.gap_d2_cm", "cm", nullptr, 1e-6, 1e3, "gap half a turn later (default: gap_d1_cm)", false),
        key_number("geometry.gap_phase_rad", "rad", 0.0, -1e3, 1e3, "phase of the gap's run-out", false),
        key_number("geometry.e1_cm", "cm", 0.0, 0.0, kInf, "disc eccentricity (at most radius_cm / 2)", false),
        key_number("geometry.e1_phase_rad", "rad", 0.0, -1e3, 1e3, "phase of the disc eccentricity", false),
        key_number("geometry.e2_cm", "cm", 0.0, 0.0, kInf, "mounting eccentricity, recorded, not in the signals (at most radius_cm / 2)", false),
        key_number("geometry.e2_phase_rad", "rad", 0.0, -1e3, 1e3, "phase of the mounting eccentricity", false),
        key_integer("harmonics[].order", "", nullptr, 2, 64, "a waveform harmonic's order (model ideal only; an array of {order, amplitude_rel, phase_rad})", false),
        key_number("harmonics[].amplitude_rel", "", nullptr, -1.0, 1.0, "its amplitude relative to the fundamental", false),
        key_number("harmonics[].phase_rad", "rad", 0.0, -1e3, 1e3, "its phase", false),
        key_number("noise.sigma_add_v", "V", 0.0, 0.0, 100.0, "additive white noise per channel, rms"),
        key_number("noise.sigma_gain", "", 0.0, 0.0, 0.5, "common multiplicative white noise, relative rms"),
        key_number("noise.drift_amplitude", "", 0.0, 0.0, 0.9, "slow common gain drift, relative amplitude", false),
        key_number("noise.drift_freq_hz", "Hz", 0.0, 0.0, 1e9, "frequency of the gain drift", false),
        key_number("noise.drift_phase_rad", "rad", 0.0, -1e3, 1e3, "phase of the gain drift", false),
        key_number("lissajous.gain_mismatch", "", 0.0, -1.0, 1.0, "gain mismatch eps: gains 1 + eps/2 (sin), 1 - eps/2 (cos)"),
        key_number("lissajous.offset_sin_v", "V", 0.0, -100.0, 100.0, "offset of the sin channel"),
        key_number("lissajous.offset_cos_v", "V", 0.0, -100.0, 100.0, "offset of the cos channel"),
        key_number("lissajous.quadrature_error_rad", "rad", 0.0, -1.5, 1.5, "quadrature error: cos channel at theta + delta"),
        key_number("front_end.reference_v", "V", nullptr, -1e3, 1e3, "the front end's reference the signals swing around (default: vmax_v * aperture_w_rad / 2 for diffraction, 0 for ideal)", false),
        key_integer("adc.bits", "bit", 0, 0, 32, "the encoder's own converter (0: none; the device digitises)"),
        key_number("adc.min_v", "V", -1.25, -1e3, 1e3, "the encoder converter's lower rail"),
        key_number("adc.max_v", "V", 1.25, -1e3, 1e3, "the encoder converter's upper rail (above adc.min_v)"),
        key_boolean("index.enabled", true, "a reference mark: one pulse per revolution (when index is given)", false),
        key_number("index.position_rad", "rad", 0.0, -1e3, 1e3, "shaft angle where the pulse starts", false),
        key_number("index.width_elec_rad", "rad", d.index.width_elec_rad, 1e-6, 1e6, "pulse width in electrical rad", false),
        key_number("index.high_v", "V", 1.0, -1e3, 1e3, "the pulse's level", false),
    });
    return t;
}

Quantizer quantizer_from_json(JsonReader& r) {
    const KeyTable& k = encoder_keys();
    Quantizer q;
    q.bits = static_cast<int>(k.integer(r, "adc.bits"));
    q.min_v = k.number(r, "adc.min_v");
    q.max_v = k.number(r, "adc.max_v");
    if (q.max_v <= q.min_v) throw ConfigError(r.path_of("max_v"), "must be greater than min_v");
    r.finish();
    return q;
}

void to_json(json& j, const Quantizer& q) { j = json{{"bits", q.bits}, {"min_v", q.min_v}, {"max_v", q.max_v}}; }

double EncoderProfile::reference_v() const {
    if (front_end_reference_v) return *front_end_reference_v;
    return model == ModelKind::Diffraction ? vmax_v * aperture_w_rad / 2.0 : 0.0;
}

double EncoderProfile::kappa_at(double gap_cm, double rho_cm) const {
    return kappa_ref * (gap_ref_cm / gap_cm) * (rho_cm / radius_cm);
}

double EncoderProfile::kappa_nominal() const { return kappa_at(0.5 * (gap_d1_cm + gap_d2_cm), radius_cm); }

double EncoderProfile::kappa_max() const {
    return kappa_at(std::min(gap_d1_cm, gap_d2_cm), radius_cm + std::fabs(e1_cm));
}

double EncoderProfile::fundamental_amplitude_v() const {
    if (model == ModelKind::Ideal) return vmax_v;
    return vmax_v * optics::fundamental_amplitude(kappa_nominal(), aperture_w_rad);
}

EncoderProfile encoder_from_json(const json& j, const std::string& path) {
    const KeyTable& k = encoder_keys();
    JsonReader r(j, path);
    EncoderProfile e;
    e.name = k.string(r, "name");
    if (r.has("description")) k.string(r, "description");
    std::string model = k.choice(r, "model");
    e.model = model == "ideal" ? ModelKind::Ideal : ModelKind::Diffraction;
    e.lines_per_rev = static_cast<int>(k.integer(r, "lines_per_rev"));
    e.radius_cm = k.number(r, "radius_cm");
    e.vmax_v = k.number(r, "vmax_v");

    if (r.has("optics")) {
        JsonReader o = r.object("optics");
        if (e.model == ModelKind::Ideal) throw ConfigError(r.path_of("optics"), "only for model 'diffraction'");
        e.aperture_w_rad = k.number(o, "optics.aperture_w_rad");
        e.kappa_ref = k.number(o, "optics.kappa_ref");
        e.gap_ref_cm = k.number(o, "optics.gap_ref_cm");
        o.finish();
    }
    if (r.has("geometry")) {
        JsonReader g = r.object("geometry");
        e.gap_d1_cm = k.number(g, "geometry.gap_d1_cm", e.gap_ref_cm);
        e.gap_d2_cm = k.number(g, "geometry.gap_d2_cm", e.gap_d1_cm);
        e.gap_phase_rad = k.number(g, "geometry.gap_phase_rad");
        e.e1_cm = k.number_in(g, "geometry.e1_cm", 0.0, 0.0, e.radius_cm / 2);
        e.e1_phase_rad = k.number(g, "geometry.e1_phase_rad");
        e.e2_cm = k.number_in(g, "geometry.e2_cm", 0.0, 0.0, e.radius_cm / 2);
        e.e2_phase_rad = k.number(g, "geometry.e2_phase_rad");
        g.finish();
    } else {
        e.gap_d1_cm = e.gap_d2_cm = e.gap_ref_cm;
    }
    if (r.has("harmonics")) {
        const json& h = r.raw("harmonics");
        if (e.model != ModelKind::Ideal) throw ConfigError(r.path_of("harmonics"), "only for model 'ideal' (diffraction harmonics follow from kappa and w)");
        if (!h.is_array()) throw ConfigError(r.path_of("harmonics"), "expected an array");
        for (std::size_t i = 0; i < h.size(); ++i) {
            JsonReader hr(h[i], r.path_of("harmonics") + "[" + std::to_string(i) + "]");
            Harmonic hm;
            hm.order = static_cast<int>(k.integer(hr, "harmonics[].order"));
            hm.amplitude_rel = k.number(hr, "harmonics[].amplitude_rel");
            hm.phase_rad = k.number(hr, "harmonics[].phase_rad");
            hr.finish();
            e.harmonics.push_back(hm);
        }
    }
    if (r.has("lissajous")) {
        JsonReader l = r.object("lissajous");
        e.lissajous.gain_mismatch = k.number(l, "lissajous.gain_mismatch");
        e.lissajous.offset_sin_v = k.number(l, "lissajous.offset_sin_v");
        e.lissajous.offset_cos_v = k.number(l, "lissajous.offset_cos_v");
        e.lissajous.quadrature_error_rad = k.number(l, "lissajous.quadrature_error_rad");
        l.finish();
    }
    if (r.has("noise")) {
        JsonReader n = r.object("noise");
        e.noise.sigma_add_v = k.number(n, "noise.sigma_add_v");
        e.noise.sigma_gain = k.number(n, "noise.sigma_gain");
        e.noise.drift_amplitude = k.number(n, "noise.drift_amplitude");
        e.noise.drift_freq_hz = k.number(n, "noise.drift_freq_hz");
        e.noise.drift_phase_rad = k.number(n, "noise.drift_phase_rad");
        n.finish();
    }
    if (r.has("front_end")) {
        JsonReader f = r.object("front_end");
        e.front_end_reference_v = k.optional_number(f, "front_end.reference_v");
        f.finish();
    }
    if (r.has("adc")) {
        JsonReader a = r.object("adc");
        e.adc = quantizer_from_json(a);
    }
    if (r.has("index")) {
        JsonReader x = r.object("index");
        e.index.enabled = k.boolean(x, "index.enabled");
        e.index.position_rad = k.number(x, "index.position_rad");
        e.index.width_elec_rad = k.number(x, "index.width_elec_rad");
        e.index.high_v = k.number(x, "index.high_v");
        x.finish();
    }
    r.finish();
    return e;
}

void to_json(json& j, const EncoderProfile& e) {
    j = json::object();
    j["name"] = e.name;
    j["model"] = e.model == ModelKind::Ideal ? "ideal" : "diffraction";
    j["lines_per_rev"] = e.lines_per_rev;
    j["radius_cm"] = e.radius_cm;
    j["vmax_v"] = e.vmax_v;
    if (e.model == ModelKind::Diffraction)
        j["optics"] = {{"aperture_w_rad", e.aperture_w_rad}, {"kappa_ref", e.kappa_ref}, {"gap_ref_cm", e.gap_ref_cm}};
    j["geometry"] = {{"gap_d1_cm", e.gap_d1_cm}, {"gap_d2_cm", e.gap_d2_cm}, {"gap_phase_rad", e.gap_phase_rad},
                     {"e1_cm", e.e1_cm}, {"e1_phase_rad", e.e1_phase_rad}, {"e2_cm", e.e2_cm},
                     {"e2_phase_rad", e.e2_phase_rad}};
    if (e.model == ModelKind::Ideal) {
        j["harmonics"] = json::array();
        for (const auto& h : e.harmonics)
            j["harmonics"].push_back({{"order", h.order}, {"amplitude_rel", h.amplitude_rel}, {"phase_rad", h.phase_rad}});
    }
    j["lissajous"] = {{"gain_mismatch", e.lissajous.gain_mismatch}, {"offset_sin_v", e.lissajous.offset_sin_v},
                      {"offset_cos_v", e.lissajous.offset_cos_v}, {"quadrature_error_rad", e.lissajous.quadrature_error_rad}};
    j["noise"] = {{"sigma_add_v", e.noise.sigma_add_v}, {"sigma_gain", e.noise.sigma_gain},
                  {"drift_amplitude", e.noise.drift_amplitude}, {"drift_freq_hz", e.noise.drift_freq_hz},
                  {"drift_phase_rad", e.noise.drift_phase_rad}};
    j["front_end"] = {{"reference_v", e.reference_v()}};
    j["adc"] = e.adc;
    j["index"] = {{"enabled", e.index.enabled}, {"position_rad", e.index.position_rad},
                  {"width_elec_rad", e.index.width_elec_rad}, {"high_v", e.index.high_v}};
}

}  // namespace fringe
