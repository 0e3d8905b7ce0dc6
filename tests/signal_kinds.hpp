// The kinds of signal of issue 13, short enough for the unit suite (0.25-0.3 s at 100 kHz): the
// divergence tests run every estimator on each, the ekf-auto tests compare it with an EKF
// that knows the true model and with the PCRB.
#pragma once

#include "helpers.hpp"

#include "server/engine/scenario.hpp"
#include "signal_gen/fastmath.hpp"

#include <string>
#include <vector>

namespace fringe::test {

struct SignalKind {
    std::string name;
    EncoderProfile encoder;
    MotionProfile motion;
    std::size_t samples = 25000;
};

inline EncoderProfile fixture_encoder(const std::string& scenario) {
    return load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/" + scenario + ".json").encoder;
}

// Diffraction encoder with the paper's gap (kappa 1.1149) and aperture w: w = 2.8713 rad is
// the 1.6 % duty-cycle error, w = 2.0 about 6 %, w = 0.5 about 10 % (MODEL.md 2.3).
inline EncoderProfile diffraction_w(double w_rad, int adc_bits) {
    auto e = fixture_encoder("paper-duty1p6");
    e.aperture_w_rad = w_rad;
    e.adc.bits = adc_bits;
    return e;
}

inline std::vector<SignalKind> signal_kinds() {
    std::vector<SignalKind> k;
    const int lines = 1024;
    {  // ideal quadrature, noise, 16- and 10-bit ADC, 0.1 % gain mismatch
        auto e = clean_ideal(lines);
        e.noise.sigma_add_v = 2e-4;
        e.noise.sigma_gain = 1e-4;
        e.lissajous.gain_mismatch = 1e-3;
        e.adc.bits = 16;
        k.push_back({"ideal-16bit", e, constant_electrical(106.7, lines)});
        e.adc.bits = 10;
        k.push_back({"ideal-10bit", e, constant_electrical(106.7, lines)});
    }
    k.push_back({"paper-duty1p6", fixture_encoder("paper-duty1p6"), constant_electrical(106.72358591248666, lines)});
    {  // eccentricity and gap run-out: kappa 1.0..1.115 once per revolution of 64 lines
        auto e = fixture_encoder("eccentricity-runout");
        k.push_back({"runout", e, constant_electrical(106.72358591248666, e.lines_per_rev)});
    }
    k.push_back({"light-drift", fixture_encoder("agc-drift"), constant_electrical(106.72358591248666, lines)});
    {  // fast acceleration (20 -> ~910 Hz electrical in 0.4 s, 2250 Hz in 1 s) with small offsets
        auto e = fixture_encoder("paper-duty1p6");
        e.lissajous.offset_sin_v = 0.01;
        e.lissajous.offset_cos_v = -0.008;
        MotionProfile m;
        m.kind = MotionKind::Ramp;
        m.velocity_rad_s = kTwoPi * 20.0 / lines;
        m.accel_rad_s2 = 1.4e4 / lines;  // electrical rad/s^2 over lines
        k.push_back({"acceleration", e, m});
    }
    {  // velocity reversals (5 Hz, peak 200 Hz electrical) with Lissajous errors and a 3rd harmonic
        auto e = clean_ideal(lines);
        e.noise.sigma_add_v = 2e-4;
        e.noise.sigma_gain = 1e-4;
        e.adc.bits = 16;
        e.lissajous = {0.02, 0.02, -0.015, 0.02};  // eps, o_s, o_c, delta
        e.harmonics = {{3, 0.02, 0.3}};
        MotionProfile m;
        m.kind = MotionKind::Sine;
        m.freq_hz = 5.0;
        m.amplitude_rad = 200.0 / 5.0 / lines;  // peak electrical rate 2*pi*200 rad/s
        k.push_back({"reversals", e, m, 30000});
    }
    return k;
}

}  // namespace fringe::test
