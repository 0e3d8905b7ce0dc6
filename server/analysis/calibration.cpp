#include "calibration.hpp"

#include "signal_gen/fastmath.hpp"

#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>

namespace fringe {

namespace {

struct Record {
    const std::vector<ErrorHarmonic>& h;
    double mean;
    double value(double s) const {  // e(s), mean included
        double v = mean;
        for (const auto& x : h) v += x.amplitude_rad * std::cos(x.order * s - x.phase_rad);
        return v;
    }
    double slope(double s) const {
        double v = 0;
        for (const auto& x : h) v -= x.order * x.amplitude_rad * std::sin(x.order * s - x.phase_rad);
        return v;
    }
};

std::string fmt17(double v) {
    char b[40];
    std::snprintf(b, sizeof b, "%.17g", v);
    return b;
}

}  // namespace

PeriodicFit periodic_correction(const std::vector<ErrorHarmonic>& error, double mean_rad, const PeriodicOptions& o) {
    if (o.table_size < 2) throw std::invalid_argument("table size must be at least 2");
    if (o.harmonics < 1) throw std::invalid_argument("harmonics must be at least 1");
    if (o.grid < 4 * static_cast<std::size_t>(o.harmonics) + 4) throw std::invalid_argument("grid too coarse for the harmonics");
    const Record r{error, mean_rad};
    const std::size_t m = o.grid;
    PeriodicFit f;
    double e2 = 0;
    for (std::size_t j = 0; j < m; ++j) {
        const double s = kTwoPi * static_cast<double>(j) / static_cast<double>(m);
        f.max_slope = std::max(f.max_slope, std::fabs(r.slope(s)));
        e2 += (r.value(s) - mean_rad) * (r.value(s) - mean_rad);
    }
    f.error_rms_rad = std::sqrt(e2 / static_cast<double>(m));
    if (!(f.max_slope < 0.9))
        throw std::invalid_argument("the error's slope against the angle reaches " + std::to_string(f.max_slope) +
                                    ": the angle read is not monotonic enough to index a correction by");
    // c(phi_j) on a uniform grid of the angle read: s = phi - e(s) contracts (|e'| < 0.9).
    std::vector<double> c(m);
    for (std::size_t j = 0; j < m; ++j) {
        const double phi = kTwoPi * static_cast<double>(j) / static_cast<double>(m);
        double s = phi - r.value(phi);
        for (int it = 0; it < 200; ++it) {
            const double next = phi - r.value(s);
            const bool done = std::fabs(next - s) < 1e-16;
            s = next;
            if (done) break;
        }
        c[j] = r.value(s) - mean_rad;
    }
    // Its Fourier coefficients (exact for orders below m/2 of the band-limited part).
    auto& corr = f.correction;
    corr.cos_k.assign(static_cast<std::size_t>(o.harmonics), 0.0);
    corr.sin_k.assign(static_cast<std::size_t>(o.harmonics), 0.0);
    for (int k = 1; k <= o.harmonics; ++k) {
        double a = 0, b = 0;
        for (std::size_t j = 0; j < m; ++j) {
            const double x = kTwoPi * static_cast<double>(k) * static_cast<double>(j) / static_cast<double>(m);
            a += c[j] * std::cos(x);
            b += c[j] * std::sin(x);
        }
        corr.cos_k[static_cast<std::size_t>(k - 1)] = 2.0 * a / static_cast<double>(m);
        corr.sin_k[static_cast<std::size_t>(k - 1)] = 2.0 * b / static_cast<double>(m);
    }
    corr.tabulate(o.table_size);
    // What the table leaves, less its mean over the angle: the offset takes a constant (with 3
    // entries the residual's mean was 1.2e-2 rad of a 2.0e-2 figure; 1.57e-2 was measured).
    double d1 = 0, d2 = 0;
    for (std::size_t j = 0; j < m; ++j) {
        const double phi = kTwoPi * (static_cast<double>(j) + 0.5) / static_cast<double>(m);
        // c at the grid's mid-points, linearly between the grid's values (m >> N: far finer than the table)
        const double cv = 0.5 * (c[j] + c[(j + 1) % m]);
        const double d = cv - corr.table_value(phi);
        d1 += d;
        d2 += d * d;
    }
    const double dm = d1 / static_cast<double>(m);
    f.table_residual_rms_rad = std::sqrt(std::max(0.0, d2 / static_cast<double>(m) - dm * dm));
    return f;
}

std::string correction_csv(const est::Correction& c) {
    std::string s = "angle_rad,correction_rad\n";
    const std::size_t n = c.table.size();
    for (std::size_t i = 0; i < n; ++i)
        s += fmt17(kTwoPi * static_cast<double>(i) / static_cast<double>(n)) + "," + fmt17(c.offset_rad + c.table[i]) + "\n";
    return s;
}

std::string correction_c_header(const est::Correction& c, double lsb_rad, const std::string& name) {
    if (!(lsb_rad > 0) || !std::isfinite(lsb_rad)) throw std::invalid_argument("the LSB must be a positive number of radians");
    const std::size_t n = c.table.size();
    if (n == 0) throw std::invalid_argument("the correction has no table");
    std::string body;
    for (std::size_t i = 0; i < n; ++i) {
        const double v = c.offset_rad + c.table[i];
        const double q = std::nearbyint(v / lsb_rad);
        if (!(std::fabs(q) <= 32767))
            throw std::invalid_argument("entry " + std::to_string(i) + " (" + fmt17(v) + " rad) does not fit int16 at " +
                                        fmt17(lsb_rad) + " rad per LSB");
        body += (i % 8 == 0 ? "\n    " : " ") + std::to_string(static_cast<int>(q)) + (i + 1 < n ? "," : "");
    }
    std::string h;
    h += "/* Angle correction table generated by fringe calibrate (docs/calibration.md).\n";
    h += " * " + std::to_string(n) + " int16 entries over one electrical period: entry i is the correction (the\n";
    h += " * offset included) at the electrical angle phi = 2*pi*i/" + std::to_string(n) + " (entry 0 at angle 0), in units of " + fmt17(lsb_rad) + " rad.\n";
    h += " * Between entries, interpolate LINEARLY; entry " + std::to_string(n) + " is entry 0 (wrap at 2*pi).\n";
    h += " * SUBTRACT the interpolated value from the angle phi read (after the Lissajous stage):\n";
    h += " *     theta = phi - " + name + "_lsb_rad * interp(" + name + ", phi)\n";
    h += " */\n#pragma once\n#include <stdint.h>\n\n";
    h += "#define " + name + "_size " + std::to_string(n) + "\n";
    h += "static const double " + name + "_lsb_rad = " + fmt17(lsb_rad) + ";\n";
    h += "static const int16_t " + name + "[" + std::to_string(n) + "] = {" + body + "\n};\n";
    return h;
}

}  // namespace fringe
