#include "encoder.hpp"

#include "signal_gen/base/config.hpp"
#include "fastmath.hpp"
#include "optics.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>

namespace fringe {

using nlohmann::json;

Quantizer quantizer_from_json(JsonReader& r) {
    Quantizer q;
    q.bits = static_cast<int>(r.integer("bits", 0, 0, 32));
    q.min_v = r.number("min_v", -1.25, -1e3, 1e3);
    q.max_v = r.number("max_v", 1.25, -1e3, 1e3);
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
    JsonReader r(j, path);
    EncoderProfile e;
    e.name = r.string("name", e.name);
    if (r.has("description")) r.string("description");
    std::string model = r.choice("model", "diffraction", {"diffraction", "ideal"});
    e.model = model == "ideal" ? ModelKind::Ideal : ModelKind::Diffraction;
    e.lines_per_rev = static_cast<int>(r.integer("lines_per_rev", e.lines_per_rev, 1, 1 << 24));
    e.radius_cm = r.number("radius_cm", e.radius_cm, 1e-3, 1e3);
    e.vmax_v = r.number("vmax_v", e.vmax_v, 1e-6, 1e3);

    if (r.has("optics")) {
        JsonReader o = r.object("optics");
        if (e.model == ModelKind::Ideal) throw ConfigError(r.path_of("optics"), "only for model 'diffraction'");
        e.aperture_w_rad = o.number("aperture_w_rad", e.aperture_w_rad, 1e-6, kTwoPi);
        e.kappa_ref = o.number("kappa_ref", e.kappa_ref, 1e-3, 50.0);
        e.gap_ref_cm = o.number("gap_ref_cm", e.gap_ref_cm, 1e-6, 1e3);
        o.finish();
    }
    if (r.has("geometry")) {
        JsonReader g = r.object("geometry");
        e.gap_d1_cm = g.number("gap_d1_cm", e.gap_ref_cm, 1e-6, 1e3);
        e.gap_d2_cm = g.number("gap_d2_cm", e.gap_d1_cm, 1e-6, 1e3);
        e.gap_phase_rad = g.number("gap_phase_rad", 0.0, -1e3, 1e3);
        e.e1_cm = g.number("e1_cm", 0.0, 0.0, e.radius_cm / 2);
        e.e1_phase_rad = g.number("e1_phase_rad", 0.0, -1e3, 1e3);
        e.e2_cm = g.number("e2_cm", 0.0, 0.0, e.radius_cm / 2);
        e.e2_phase_rad = g.number("e2_phase_rad", 0.0, -1e3, 1e3);
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
            hm.order = static_cast<int>(hr.integer("order", 2, 64));
            hm.amplitude_rel = hr.number("amplitude_rel", -1.0, 1.0);
            hm.phase_rad = hr.number("phase_rad", 0.0, -1e3, 1e3);
            hr.finish();
            e.harmonics.push_back(hm);
        }
    }
    if (r.has("lissajous")) {
        JsonReader l = r.object("lissajous");
        e.lissajous.gain_mismatch = l.number("gain_mismatch", 0.0, -1.0, 1.0);
        e.lissajous.offset_sin_v = l.number("offset_sin_v", 0.0, -100.0, 100.0);
        e.lissajous.offset_cos_v = l.number("offset_cos_v", 0.0, -100.0, 100.0);
        e.lissajous.quadrature_error_rad = l.number("quadrature_error_rad", 0.0, -1.5, 1.5);
        l.finish();
    }
    if (r.has("noise")) {
        JsonReader n = r.object("noise");
        e.noise.sigma_add_v = n.number("sigma_add_v", 0.0, 0.0, 100.0);
        e.noise.sigma_gain = n.number("sigma_gain", 0.0, 0.0, 0.5);
        e.noise.drift_amplitude = n.number("drift_amplitude", 0.0, 0.0, 0.9);
        e.noise.drift_freq_hz = n.number("drift_freq_hz", 0.0, 0.0, 1e9);
        e.noise.drift_phase_rad = n.number("drift_phase_rad", 0.0, -1e3, 1e3);
        n.finish();
    }
    if (r.has("front_end")) {
        JsonReader f = r.object("front_end");
        e.front_end_reference_v = f.optional_number("reference_v", -1e3, 1e3);
        f.finish();
    }
    if (r.has("adc")) {
        JsonReader a = r.object("adc");
        e.adc = quantizer_from_json(a);
    }
    if (r.has("index")) {
        JsonReader x = r.object("index");
        e.index.enabled = x.boolean("enabled", true);
        e.index.position_rad = x.number("position_rad", 0.0, -1e3, 1e3);
        e.index.width_elec_rad = x.number("width_elec_rad", e.index.width_elec_rad, 1e-6, 1e6);
        e.index.high_v = x.number("high_v", 1.0, -1e3, 1e3);
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
