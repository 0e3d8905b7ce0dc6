// Evaluate one estimator on a capture (the engine behind `fringe estimate`): stream the
// capture in blocks through the estimator, write the estimates, and score against truth when
// the capture has theta_true.
#pragma once

#include "drivers/abz.hpp"
#include "drivers/capture_file.hpp"
#include "signal_gen/encoder.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <cstdio>
#include <functional>
#include <optional>
#include <string>

namespace fringe {

struct EvaluateOptions {
    std::string capture_path;
    std::string estimator;
    nlohmann::json params = nlohmann::json::object();
    // What the estimator is told about the encoder; default: the capture's sidecar/header.
    std::optional<EncoderProfile> encoder;
    double settle_s = 0.1;
    int max_harmonic = 16;
    std::string estimates_path;  // optional CSV t,theta_rad,omega_rad_s,valid
    std::size_t block = 65536;
    std::function<void(std::uint64_t done)> progress;
    CaptureOptions capture;            // a sigrok session's channel map
    // The DUT's ABZ readout (docs/abz.md): decode the capture's a/b/z lines and score them as
    // "dut" beside the estimator (report "dut").
    std::optional<AbzConfig> abz;
};

// The report (schema "fringe.estimate", version 1). Throws ConfigError / CaptureError /
// est::EstimatorError on bad input; the estimates file is complete up to the failure.
nlohmann::json evaluate_capture(const EvaluateOptions& o);

// Estimates CSV writer (t,theta_rad,omega_rad_s,valid; README "The commands"), shortest round-trip number formatting.
class EstimatesWriter {
public:
    explicit EstimatesWriter(const std::string& path);
    ~EstimatesWriter() { if (f_) std::fclose(f_); }  // on an error path: what was written stays
    EstimatesWriter(const EstimatesWriter&) = delete;
    EstimatesWriter& operator=(const EstimatesWriter&) = delete;
    void write(std::size_t n, const double* t, const double* theta, const double* omega, const std::uint8_t* valid);
    void close();

private:
    std::string path_;
    std::FILE* f_ = nullptr;
    std::string buf_;
};

}  // namespace fringe
