// Branch-free sin/cos that GCC vectorises over a block. glibc's scalar sin+cos costs ~14 ns
// here, which alone would cap the generator near 70 M samples/s. Cody-Waite reduction by
// pi/2 in three parts, Taylor polynomials on [-pi/4, pi/4] (truncation < 1e-19), so the
// error is ~1 ulp for |x| < kFastSinCosMaxArg. Callers fall back to std::sin/std::cos
// beyond that (checked per block, see generator.cpp).
#pragma once

#include <cmath>
#include <cstdint>

namespace fringe {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 6.28318530717958647692;

// |x| below this keeps kd*kPio2Hi exact (kd < 2^20 and kPio2Hi has 33 significant bits).
constexpr double kFastSinCosMaxArg = 1.0e6;

inline void fast_sincos(double x, double& s_out, double& c_out) {
    constexpr double kTwoOverPi = 0.63661977236758134308;
    constexpr double kPio2Hi = 1.57079632673412561417e+00;   // first 33 bits of pi/2
    constexpr double kPio2Mid = 6.07710050630396597660e-11;  // next 33 bits
    constexpr double kPio2Lo = 2.02226624871116645580e-21;   // remainder
    constexpr double kRound = 6755399441055744.0;            // 1.5 * 2^52: round to nearest
    const double kd = (x * kTwoOverPi + kRound) - kRound;
    const double r = ((x - kd * kPio2Hi) - kd * kPio2Mid) - kd * kPio2Lo;
    const double r2 = r * r;
    // sin r = r - r^3/3! + ... - r^19/19! ; cos r = 1 - r^2/2! + ... - r^18/18!
    const double sin_r =
        r - r * r2 * (1.0 / 6.0 - r2 * (1.0 / 120.0 - r2 * (1.0 / 5040.0 - r2 * (1.0 / 362880.0 - r2 * (1.0 / 39916800.0 - r2 * (1.0 / 6227020800.0 - r2 * (1.0 / 1307674368000.0 - r2 * (1.0 / 355687428096000.0 - r2 * (1.0 / 121645100408832000.0)))))))));
    const double cos_r =
        1.0 - r2 * (0.5 - r2 * (1.0 / 24.0 - r2 * (1.0 / 720.0 - r2 * (1.0 / 40320.0 - r2 * (1.0 / 3628800.0 - r2 * (1.0 / 479001600.0 - r2 * (1.0 / 87178291200.0 - r2 * (1.0 / 20922789888000.0 - r2 * (1.0 / 6402373705728000.0)))))))));
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
