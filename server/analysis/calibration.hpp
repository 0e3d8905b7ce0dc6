// Calibration of an arctangent (docs/calibration.md): the numerical part of `fringe calibrate`.
// The correction's format and how it is applied are estimator/correction.hpp (an estimator
// applies it; the estimator library cannot depend on this one). Here: the Lissajous stage from
// an ellipse fit of the signals, the periodic stage from a record of the error against the
// angle, the predicted residual, and the exports (CSV table, C header).
//
// Sign convention: the correction c(phi) is the error (estimate minus truth) at the angle phi
// the estimator reads, and is SUBTRACTED from that angle.
#pragma once

#include "estimator/correction.hpp"
#include "estimator/ellipse.hpp"

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace fringe {

// The Lissajous stage from the signals: the Heydemann fit atan2-ellipse runs (estimator/ellipse.hpp)
// over every sample given.
class LissajousIdentifier {
public:
    void add(std::size_t n, const double* sin_v, const double* cos_v) {
        for (std::size_t i = 0; i < n; ++i) acc_.add(sin_v[i], cos_v[i]);
    }
    // Empty on success (cal set), else why the fit was rejected.
    std::string finish(est::Calibration& cal) const { return est::fit_ellipse(acc_, cal); }
    double points() const { return acc_.points; }

private:
    est::ConicAccumulator acc_;
};

// One harmonic of an error record against an angle s (the truth, or the self-referenced
// reference): amplitude * cos(order * s - phase), the convention of the report's harmonics.
struct ErrorHarmonic {
    int order = 0;
    double amplitude_rad = 0, phase_rad = 0;
};

struct PeriodicOptions {
    std::size_t table_size = 64;  // N
    int harmonics = 16;           // K of the correction's coefficients
    std::size_t grid = 8192;      // points over a period for the inversion and the rms figures
};

struct PeriodicFit {
    est::Correction correction;   // cos_k, sin_k and the table (no Lissajous stage)
    double error_rms_rad = 0;     // rms of the record's periodic error (what the correction removes)
    double table_residual_rms_rad = 0;  // std over the angle of what the table leaves of it (its mean is the offset's)
    double max_slope = 0;         // max |de/ds|: the inversion needs it below 1
};

// The error record e(s) = mean_rad + sum_k A_k cos(k s - phase_k) is against the angle s; the
// estimator reads phi = s + e(s). The correction is indexed by phi, so it is e(s(phi)) - mean_rad
// with s(phi) solved by fixed-point iteration (this inversion matters: with a 1.8e-2 rad error
// at 1x and 3x, indexing by s instead of phi leaves 1e-3 rad). Throws std::invalid_argument
// when |de/ds| reaches 0.9 (the reading is not monotonic enough to invert).
PeriodicFit periodic_correction(const std::vector<ErrorHarmonic>& error, double mean_rad, const PeriodicOptions& o = {});

// What the corrected estimator should reach: the table's residual and the error the record
// could not attribute to the angle (noise, unfitted orders), added in quadrature.
inline double predicted_residual_rad(double table_residual_rms_rad, double noise_rms_rad) {
    return std::hypot(table_residual_rms_rad, noise_rms_rad);
}

// The same on another capture, from a record of n_samples scored samples with `orders` harmonics
// fitted (2 orders + 1 coefficients with the mean): the record's residual noise is low by the
// coefficients fitted (x n / (n - 2 orders - 1)), and the table carries the fit's own noise
// (each coefficient's variance 2 sigma^2 / n: over the angle sigma^2 2 orders / n). White noise
// and angles covered evenly; on a 128-step sweep with 15 orders this is x1.28 on the noise.
inline double predicted_residual_rad(double table_residual_rms_rad, double noise_rms_rad, double n_samples, int orders) {
    const double p = 2.0 * orders + 1.0;
    if (!(n_samples > p)) return predicted_residual_rad(table_residual_rms_rad, noise_rms_rad);
    const double noise_var = noise_rms_rad * noise_rms_rad * n_samples / (n_samples - p) * (1.0 + 2.0 * orders / n_samples);
    return std::sqrt(table_residual_rms_rad * table_residual_rms_rad + noise_var);
}

// angle_rad,correction_rad per table entry, the offset included (a header line, then N lines,
// 17 significant digits).
std::string correction_csv(const est::Correction& c);

// A C header with the table, the offset included, as int16 at lsb_rad per count (rounded to nearest; throws
// std::invalid_argument when an entry does not fit), the layout and interpolation in a comment.
std::string correction_c_header(const est::Correction& c, double lsb_rad, const std::string& name = "fringe_correction");

}  // namespace fringe
