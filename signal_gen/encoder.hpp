// Encoder profile: everything MODEL.md section 2 needs to synthesise one encoder.
// JSON keys carry units; see docs/schema.md for the full schema.
#pragma once

#include "quantizer.hpp"

#include <nlohmann/json_fwd.hpp>

#include <optional>
#include <string>
#include <vector>

namespace fringe {

enum class ModelKind { Diffraction, Ideal };

struct Harmonic {  // ideal model: a common waveform shape term h*sin(m*x + psi)
    int order = 2;
    double amplitude_rel = 0.0;  // relative to the fundamental
    double phase_rad = 0.0;
};

struct LissajousErrors {
    double gain_mismatch = 0.0;         // eps: channel gains (1 + eps/2, 1 - eps/2)
    double offset_sin_v = 0.0;
    double offset_cos_v = 0.0;
    double quadrature_error_rad = 0.0;  // delta: cos channel evaluated at theta + delta
};

struct NoiseConfig {
    double sigma_add_v = 0.0;      // eta2: additive white noise per channel, V rms
    double sigma_gain = 0.0;       // eta1: common multiplicative white noise, relative rms
    double drift_amplitude = 0.0;  // slow common gain drift, relative amplitude
    double drift_freq_hz = 0.0;
    double drift_phase_rad = 0.0;
};

struct IndexConfig {  // reference mark: one pulse per revolution
    bool enabled = false;
    double position_rad = 0.0;        // shaft angle where the pulse starts
    double width_elec_rad = 6.283185307179586;  // pulse width in electrical rad (one line)
    double high_v = 1.0;
};

struct EncoderProfile {
    std::string name = "unnamed";
    ModelKind model = ModelKind::Diffraction;
    int lines_per_rev = 1024;
    double radius_cm = 2.5;     // nominal track radius r
    double vmax_v = 1.0;        // diffraction: source/detector scale; ideal: amplitude

    // Diffraction optics (MODEL.md 2.1-2.2)
    double aperture_w_rad = 2.8713;  // detector aperture in electrical rad
    double kappa_ref = 1.0;          // kappa at gap_ref_cm and r
    double gap_ref_cm = 0.747;

    // Geometry (MODEL.md 2.4): D(phi) = (d1+d2)/2 + (d1-d2)/2 cos(phi + gap_phase)
    double gap_d1_cm = 0.747;
    double gap_d2_cm = 0.747;
    double gap_phase_rad = 0.0;
    double e1_cm = 0.0;  // disc eccentricity
    double e1_phase_rad = 0.0;
    double e2_cm = 0.0;  // mounting eccentricity: recorded, not in the signals
    double e2_phase_rad = 0.0;

    std::vector<Harmonic> harmonics;  // ideal model only
    LissajousErrors lissajous;
    NoiseConfig noise;
    std::optional<double> front_end_reference_v;  // default: Vmax*w/2 (diffraction), 0 (ideal)
    Quantizer adc;
    IndexConfig index;

    double reference_v() const;
    // kappa for a gap D and read radius rho: kappa_ref * (D_ref/D) * (rho/r).
    double kappa_at(double gap_cm, double rho_cm) const;
    double kappa_nominal() const;  // at the mean gap and rho = r
    double kappa_max() const;      // over gap run-out and eccentricity
    bool geometry_varies() const { return gap_d1_cm != gap_d2_cm || e1_cm != 0.0; }
    // Fundamental amplitude after the front end at the nominal kappa, V.
    double fundamental_amplitude_v() const;
};

EncoderProfile encoder_from_json(const nlohmann::json& j, const std::string& path = "encoder");
void to_json(nlohmann::json& j, const EncoderProfile& e);

}  // namespace fringe
