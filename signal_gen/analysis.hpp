// Signal analysis shared by the CLI summary, the scorer and tests.
#pragma once

#include <cstddef>
#include <vector>

namespace fringe {

// Least-squares fit of v on [1, cos(k*theta), sin(k*theta)], k = 1..K. Works for any
// sampling of theta (reversals, non-uniform). amplitude[k-1] = sqrt(a_k^2 + b_k^2) for
// v ~ a_k cos(k theta) + b_k sin(k theta).
struct HarmonicFit {
    double dc = 0.0;
    std::vector<double> cos_coef, sin_coef, amplitude;
};
HarmonicFit fit_harmonics(const double* v, const double* theta_rad, std::size_t n, int K);

// Fraction of samples strictly above the mid level (max + min)/2: a comparator at 50 %
// amplitude (MODEL.md 2.3). Meaningful over whole signal periods.
double duty_cycle(const double* v, std::size_t n);

}  // namespace fringe
