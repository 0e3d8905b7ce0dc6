// ADC/DAC quantiser (MODEL.md 2.5): B bits over [min_v, max_v), mid-tread, clipping.
//   q = (max_v - min_v)/2^B, code = clip(floor((v - min_v)/q + 1/2), 0, 2^B - 1),
//   output = min_v + code*q.
// bits == 0 means an ideal converter (no quantisation, no clipping).
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <cmath>
#include <cstdint>

namespace fringe {

class JsonReader;

struct Quantizer {
    int bits = 0;
    double min_v = -1.25;
    double max_v = 1.25;

    bool ideal() const { return bits == 0; }
    double levels() const { return static_cast<double>(std::uint64_t{1} << bits); }  // exact 2^B
    double step_v() const { return (max_v - min_v) / levels(); }
    double max_code() const { return levels() - 1.0; }
    // 1/q: multiplying by it is the documented (v - min_v)/q up to rounding at exact ties,
    // and much cheaper than a division per sample.
    double inv_step() const { return levels() / (max_v - min_v); }
    // Nearest level index before clipping: floor((v - min_v)/q + 1/2).
    double raw_code(double v) const { return std::floor((v - min_v) * inv_step() + 0.5); }
    double code(double v) const { return clamp_code(raw_code(v), max_code()); }
    // Comparisons rather than std::fmin/fmax: those are libm calls that block vectorising.
    static double clamp_code(double c, double top) { return c < 0.0 ? 0.0 : (c > top ? top : c); }
    double apply(double v) const { return ideal() ? v : quantize(v, min_v, inv_step(), step_v(), max_code()); }
    // The quantiser with its constants passed in, so a per-sample loop can hoist them and
    // still vectorise (a call to apply() per sample does not).
    static double quantize(double v, double lo, double inv_q, double q, double top) {
        return lo + clamp_code(std::floor((v - lo) * inv_q + 0.5), top) * q;
    }
    bool clips(double v) const {
        if (ideal()) return false;
        const double c = raw_code(v);
        return c < 0.0 || c > max_code();
    }
};

Quantizer quantizer_from_json(JsonReader& r);
void to_json(nlohmann::json& j, const Quantizer& q);

}  // namespace fringe
