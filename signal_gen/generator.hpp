// Synthesis of the encoder's sin/cos signals along a motion profile, with exact truth
// (MODEL.md section 2). Stateless per sample: sample k depends only on (profile, motion,
// rate, seed, k), so any block partition gives identical output.
#pragma once

#include "encoder.hpp"
#include "motion.hpp"
#include "noise.hpp"

#include <cstdint>
#include <memory>
#include <vector>

namespace fringe {

// A span of frames (structure of arrays). Signals in V, truth alongside.
struct Block {
    std::vector<double> t_s;
    std::vector<double> sin_v, cos_v;  // what the ADC delivers (front end, errors, noise, ADC)
    std::vector<double> index_v;       // reference mark (0 or high_v); empty if disabled
    std::vector<double> phi_rad;       // shaft angle
    std::vector<double> theta_rad;     // unwrapped electrical phase at the read head (e1 included)
    std::vector<double> omega_rad_s;   // d theta/dt, electrical rad/s
    std::size_t size() const { return t_s.size(); }
    void resize(std::size_t n, bool with_index);
};

class Generator {
public:
    Generator(EncoderProfile encoder, MotionProfile motion, double sample_rate_hz, std::uint64_t seed,
              double t0_s = 0.0);

    // Fill out (already sized) with samples first .. first + out.size() - 1.
    void generate(std::uint64_t first, Block& out);

    const EncoderProfile& encoder() const { return enc_; }
    const MotionProfile& motion() const { return motion_; }
    double sample_rate_hz() const { return fs_; }
    double time_of(std::uint64_t k) const { return t0_ + static_cast<double>(k) / fs_; }

    // Noise-free, unquantised channel voltages after the front end and Lissajous errors, for a
    // given electrical phase and kappa (MODEL.md 2.2, 2.5). Used by estimators' models and tests.
    void clean_channels(double theta_rad, double kappa, double& sin_v, double& cos_v) const;
    // Raw detector voltages (before the front end), gain 1, no Lissajous gain/offset.
    void raw_channels(double theta_rad, double kappa, double& sin_v, double& cos_v) const;
    int harmonic_count() const { return M_; }

private:
    struct Tile {  // views into a Block at an offset
        double *t_s, *sin_v, *cos_v, *index_v, *phi_rad, *theta_rad, *omega_rad_s;
    };
    void generate_tile(std::uint64_t first, std::size_t n, const Tile& out);
    void set_amplitudes(double kappa, double* amp) const;

    EncoderProfile enc_;
    MotionProfile motion_;
    double fs_, t0_;
    NoiseField noise_;
    int M_;                            // highest harmonic
    double dc_v_;                      // raw DC level
    std::vector<double> p_s_, q_s_, p_c_, q_c_;  // per-harmonic cos/sin weights per channel
    std::vector<double> amp_nominal_;  // per-harmonic amplitude at the nominal kappa, V
    // scratch
    std::vector<double> alpha_, s1_, c1_, kappa_, noise_s_, noise_c_, noise_g_;
};

}  // namespace fringe
