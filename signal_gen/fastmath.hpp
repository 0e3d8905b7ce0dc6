// Branch-free sin/cos that GCC vectorises over a block. glibc's scalar sin+cos costs ~14 ns
// here, which alone would cap the generator near 70 M samples/s. Cody-Waite reduction by
// pi/2 in four parts of 26, 26, 26 and 53 bits: k*part is exact for the first three while
// |k| < 2^26, and each subtraction rounds relative to its own result, so r is good to about
// an ulp. Then polynomials in z = r^2 on |r| <= pi/4: sin r = r (1 + z P(z)), cos r =
// 1 - z/2 + z^2 Q(z), with P and Q the Chebyshev-economised Taylor series (degree 6 and 5;
// truncation below 4e-18, computed in exact rational arithmetic). Callers fall back to
// std::sin/std::cos beyond kFastSinCosMaxArg (checked per block, see generator.cpp).
#pragma once

#include "signal_gen/base/constants.hpp"

#include <cmath>
#include <cstdint>

namespace fringe {

// |x| below this keeps |k| < 2^26, where the reduction below is exact. About 41 hours of
// signal at 100 kHz and 937 samples per electrical period.
constexpr double kFastSinCosMaxArg = 1.0e8;

inline void fast_sincos(double x, double& s_out, double& c_out) {
    constexpr double kTwoOverPi = 0.63661977236758134308;
    constexpr double kPio2A = 0x1.921fb50000000p+0;   // pi/2 = A + B + C + D
    constexpr double kPio2B = 0x1.110b460000000p-26;
    constexpr double kPio2C = 0x1.1a62630000000p-54;
    constexpr double kPio2D = 0x1.8a2e03707344ap-81;
    constexpr double kRound = 6755399441055744.0;    // 1.5 * 2^52: round to nearest
    const double kd = (x * kTwoOverPi + kRound) - kRound;
    const double r = (((x - kd * kPio2A) - kd * kPio2B) - kd * kPio2C) - kd * kPio2D;
    const double z = r * r;
    const double p = -1.66666666666666158e-01 + z * (8.33333333332036616e-03 + z * (-1.98412698286529752e-04 +
                     z * (2.75573133772343877e-06 + z * (-2.50507170940625882e-08 + z * 1.58947431203602702e-10))));
    const double q = 4.16666666666666644e-02 + z * (-1.38888888888873976e-03 + z * (2.48015872987663532e-05 +
                     z * (-2.75573172720311515e-07 + z * (2.08761463240985520e-09 + z * -1.13826360281909132e-11))));
    const double sin_r = r + r * (z * p);
    const double cos_r = (1.0 - 0.5 * z) + (z * z) * q;
    const auto quadrant = static_cast<std::int64_t>(kd) & 3;
    const double s = (quadrant & 1) ? cos_r : sin_r;
    const double c = (quadrant & 1) ? sin_r : cos_r;
    s_out = (quadrant & 2) ? -s : s;
    c_out = ((quadrant + 1) & 2) ? -c : c;
}

// sin and cos for |x| <= 8 (a wrapped phase plus a step), tuned for latency rather than
// throughput: the trackers' per-sample recursion runs through it. Two-part Cody-Waite
// reduction by pi/2 (exact for |k| <= 5), then Taylor polynomials in r^2 to r^15 and r^16
// (truncation < 5e-17 on [-pi/4, pi/4]) evaluated by Estrin's scheme with std::fma. fma is
// correctly rounded by IEEE 754, so results are identical on every machine, with or without
// hardware FMA (unlike letting the compiler contract a*b+c).
inline void sincos_small(double x, double& s_out, double& c_out) {
    constexpr double kTwoOverPi = 0.63661977236758134308;
    constexpr double kPio2Hi = 1.57079632673412561417e+00;
    constexpr double kPio2Lo = 6.07710050650619260148e-11;  // pi/2 - kPio2Hi
    constexpr double kRound = 6755399441055744.0;
    const double kd = (x * kTwoOverPi + kRound) - kRound;
    const double r = std::fma(-kd, kPio2Lo, std::fma(-kd, kPio2Hi, x));
    const double z = r * r, z2 = z * z, z4 = z2 * z2;
    // sin r = r*(1 - z/3! + z^2/5! - ... - z^7/15!)
    const double s01 = std::fma(-1.0 / 6.0, z, 1.0), s23 = std::fma(-1.0 / 5040.0, z, 1.0 / 120.0);
    const double s45 = std::fma(-1.0 / 39916800.0, z, 1.0 / 362880.0);
    const double s67 = std::fma(-1.0 / 1307674368000.0, z, 1.0 / 6227020800.0);
    const double sp = std::fma(std::fma(s67, z2, s45), z4, std::fma(s23, z2, s01));
    // cos r = 1 - z/2! + z^2/4! - ... + z^8/16!
    const double c01 = std::fma(-0.5, z, 1.0), c23 = std::fma(-1.0 / 720.0, z, 1.0 / 24.0);
    const double c45 = std::fma(-1.0 / 3628800.0, z, 1.0 / 40320.0);
    const double c67 = std::fma(-1.0 / 87178291200.0, z, 1.0 / 479001600.0);
    const double c8 = 1.0 / 20922789888000.0;
    const double cp = std::fma(std::fma(std::fma(c8, z2, c67), z2, c45), z4, std::fma(c23, z2, c01));
    const double sin_r = r * sp, cos_r = cp;
    const auto quadrant = static_cast<std::int64_t>(kd) & 3;
    const double sv = (quadrant & 1) ? cos_r : sin_r;
    const double cv = (quadrant & 1) ? sin_r : cos_r;
    s_out = (quadrant & 2) ? -sv : sv;
    c_out = ((quadrant + 1) & 2) ? -cv : cv;
}

// Wrap to (-pi, pi].
inline double wrap_pi(double x) {
    double y = std::remainder(x, kTwoPi);
    return y <= -kPi ? y + kTwoPi : y;
}

}  // namespace fringe
