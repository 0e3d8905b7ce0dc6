// A correction of an arctangent's angle (docs/calibration.md): what `fringe calibrate` computes
// and what atan2 applies with its parameter correction=FILE.
//
// Two stages, in order:
//  1. Lissajous: offsets, amplitudes (their ratio is the gain mismatch) and the quadrature phase
//     of the signals, applied to the signals before atan2 exactly as the nominal calibration is
//     (MODEL.md 4.1): s_n = (s - o_s)/A_s, c_n = ((c - o_c)/A_c + s_n sin(delta))/cos(delta).
//  2. Periodic: a correction c(phi) of the angle phi = atan2(s_n, c_n) read after stage 1, phi
//     wrapped to [0, 2*pi). It is SUBTRACTED: theta_corrected = phi - c(phi). So c(phi) is the
//     error the estimator makes when it reads phi (its estimate minus the truth).
//     c is given both as harmonic coefficients,
//         c(phi) = sum_{k=1..K} [cos_k cos(k phi) + sin_k sin(k phi)],
//     and as a table of N entries: entry i is c(2*pi*i/N) (entry 0 at angle 0), and between
//     entries c is interpolated LINEARLY, entry N being entry 0 (the wrap at 2*pi). The
//     estimator applies the table (what a chip or firmware loads); the coefficients are the
//     table's source and the portable form.
//  3. Offset: a constant offset_rad, subtracted as well (theta_corrected = phi - offset_rad -
//     c(phi)): the error's mean against a truth (0 when there was none to measure it against).
#pragma once

#include "signal_gen/base/params.hpp"

#include <nlohmann/json.hpp>

#include <cmath>

#include <memory>
#include <string>
#include <vector>

namespace fringe::est {

struct Calibration;

struct Correction {
    // Stage 1 (absent: the estimator's own calibration is kept).
    bool has_lissajous = false;
    double offset_sin_v = 0, offset_cos_v = 0;
    double amplitude_sin_v = 1, amplitude_cos_v = 1;
    double quadrature_error_rad = 0;
    // Stage 2: coefficients of orders 1..K (index k-1), and the table.
    std::vector<double> cos_k, sin_k;
    std::vector<double> table;
    // Stage 3.
    double offset_rad = 0;

    // Stage 1 to and from a calibration: the correction's Lissajous stage put into `cal` (and
    // cal.prepare() called), or taken from it (has_lissajous set).
    void lissajous_into(Calibration& cal) const;
    void lissajous_from(const Calibration& cal);

    // c(phi) from the coefficients; phi any angle (rad).
    double harmonic_value(double phi) const;
    // c(phi) from the table (linear interpolation with wrap); phi any angle (rad). 0 without a table.
    double table_value(double phi) const {
        const std::size_t n = table.size();
        if (n == 0) return 0.0;
        double x = phi * (static_cast<double>(n) / 6.283185307179586476925);
        x -= std::floor(x / static_cast<double>(n)) * static_cast<double>(n);  // [0, n]
        std::size_t i = static_cast<std::size_t>(x);
        if (i >= n) i = 0, x = 0;  // x rounded up to n: the wrap
        const double f = x - static_cast<double>(i);
        const double a = table[i], b = table[i + 1 == n ? 0 : i + 1];
        return a + f * (b - a);
    }
    // The table of n entries from the coefficients (entry i at 2*pi*i/n).
    void tabulate(std::size_t n);

    // fringe's JSON (schema "fringe.correction"); from_json(to_json()) is exact.
    nlohmann::json to_json() const;
    // Throws ConfigError naming the field on a malformed correction.
    static Correction from_json(const nlohmann::json& j);
    static Correction load(const std::string& path);
};

struct Calibration;
// The estimators' parameter correction=FILE.
fringe::ParamInfo correction_param();
// Reads params "correction" (null: none); a Lissajous stage replaces cal (prepared), and a
// calibration parameter beside it is refused. Throws ConfigError naming params.correction.
std::unique_ptr<Correction> correction_from_params(const fringe::Params& p, Calibration& cal);

}  // namespace fringe::est
