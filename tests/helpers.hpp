#pragma once

#include "drivers/capture_file.hpp"
#include "signal_gen/encoder.hpp"
#include "signal_gen/generator.hpp"
#include "signal_gen/motion.hpp"

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace fringe::test {

// n samples of a generator into a capture file: with its truth and encoder in the metadata, or
// as a real encoder's t,sin,cos alone.
inline void write_generated_capture(const EncoderProfile& enc, const MotionProfile& motion, double fs_hz, std::uint64_t seed, std::size_t n,
                                    const std::filesystem::path& path, bool with_truth) {
    Generator g(enc, motion, fs_hz, seed);
    Block b;
    b.resize(n, false);
    g.generate(0, b);
    const nlohmann::json meta = with_truth ? nlohmann::json{{"sample_rate_hz", fs_hz}, {"t0_s", 0.0}, {"encoder", enc}} : nlohmann::json{{"sample_rate_hz", fs_hz}};
    CaptureWriter w(path.string(), CaptureColumns{with_truth, with_truth, false}, meta);
    w.write(b);
    w.close();
}

// A fresh folder under the system's temporary folder, removed with all it holds when the
// object goes (also when a test fails).
struct TempDir {
    std::filesystem::path path;
    explicit TempDir(const std::string& prefix = "fringe-test") {
        path = std::filesystem::temp_directory_path() / (prefix + "-" + std::to_string(getpid()) + "-" + std::to_string(std::random_device{}()));
        std::filesystem::create_directories(path);
    }
    ~TempDir() {
        std::error_code ec;
        std::filesystem::remove_all(path, ec);
    }
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;
};

inline EncoderProfile clean_ideal(int lines = 1024) {
    EncoderProfile e;
    e.name = "test-ideal";
    e.model = ModelKind::Ideal;
    e.lines_per_rev = lines;
    e.vmax_v = 1.0;
    e.gap_d1_cm = e.gap_d2_cm = e.gap_ref_cm;
    return e;
}

inline EncoderProfile clean_diffraction(double kappa, double w_rad) {
    EncoderProfile e;
    e.name = "test-diffraction";
    e.model = ModelKind::Diffraction;
    e.aperture_w_rad = w_rad;
    e.kappa_ref = kappa;
    e.gap_d1_cm = e.gap_d2_cm = e.gap_ref_cm;
    return e;
}

inline MotionProfile constant_electrical(double electrical_hz, int lines) {
    MotionProfile m;
    m.kind = MotionKind::Constant;
    m.velocity_rad_s = 2 * 3.14159265358979323846 * electrical_hz / lines;
    return m;
}

inline Block generate(const EncoderProfile& e, const MotionProfile& m, double fs, std::size_t n,
                      std::uint64_t seed = 1) {
    Generator g(e, m, fs, seed);
    Block b;
    b.resize(n, e.index.enabled);
    g.generate(0, b);
    return b;
}

// Independent demodulation: atan2 of the channels, unwrapped (MODEL.md 4.1 with no correction).
inline std::vector<double> atan2_phase(const Block& b) {
    std::vector<double> out(b.size());
    double prev = 0, acc = 0;
    for (std::size_t i = 0; i < b.size(); ++i) {
        double a = std::atan2(b.sin_v[i], b.cos_v[i]);
        if (i == 0) acc = a;
        else {
            double d = a - prev;
            d -= 2 * 3.14159265358979323846 * std::round(d / (2 * 3.14159265358979323846));
            acc += d;
        }
        prev = a;
        out[i] = acc;
    }
    return out;
}

}  // namespace fringe::test
