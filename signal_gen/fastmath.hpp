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

// Wrap to (-pi, pi].
inline double wrap_pi(double x) {
    double y = std::remainder(x, kTwoPi);
    return y <= -kPi ? y + kTwoPi : y;
}

}  // namespace fringe
