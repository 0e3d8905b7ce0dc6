// The normal generator against the normal distribution's analytic moments and tails.
#include "signal_gen/noise.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <vector>

using namespace fringe;
using Catch::Matchers::WithinAbs;

TEST_CASE("ziggurat normals have the moments and tail mass of N(0,1)", "[noise]") {
    Xoshiro256pp rng(12345);
    const int N = 4000000;
    double m1 = 0, m2 = 0, m3 = 0, m4 = 0;
    long beyond1 = 0, beyond2 = 0, beyond3 = 0, beyond_r = 0;
    for (int i = 0; i < N; ++i) {
        double x = standard_normal(rng);
        m1 += x; m2 += x * x; m3 += x * x * x; m4 += x * x * x * x;
        double a = std::fabs(x);
        beyond1 += a > 1; beyond2 += a > 2; beyond3 += a > 3; beyond_r += a > 3.442619855899;
    }
    m1 /= N; m2 /= N; m3 /= N; m4 /= N;
    // Standard errors: mean 1/sqrt(N) = 5e-4, var sqrt(2/N) = 7e-4, skew sqrt(15/N) ~ 2e-3, kurt ~ sqrt(96/N) ~ 5e-3
    CHECK_THAT(m1, WithinAbs(0.0, 5 * 5e-4));
    CHECK_THAT(m2, WithinAbs(1.0, 5 * 7e-4));
    CHECK_THAT(m3, WithinAbs(0.0, 5 * 2e-3));
    CHECK_THAT(m4, WithinAbs(3.0, 5 * 5e-3));
    auto p_beyond = [](double z) { return std::erfc(z / std::sqrt(2.0)); };
    auto check_tail = [&](long count, double z) {
        double p = p_beyond(z);
        double sd = std::sqrt(p * (1 - p) / N);
        CHECK_THAT(double(count) / N, WithinAbs(p, 5 * sd));
    };
    check_tail(beyond1, 1.0);
    check_tail(beyond2, 2.0);
    check_tail(beyond3, 3.0);
    check_tail(beyond_r, 3.442619855899);  // the ziggurat's tail algorithm
}

TEST_CASE("noise field: a function of (seed, sample) only", "[noise]") {
    NoiseField a(9, 1, 2), b(9, 1, 2), c(10, 1, 2);
    std::vector<double> a0(10000), a1(10000), b0(10000), b1(10000), c0(10000), c1(10000);
    double* pa[2] = {a0.data(), a1.data()};
    a.fill(100, 10000, pa);
    // b fills in reverse, odd-sized pieces
    for (std::size_t off = 10000; off > 0;) {
        std::size_t n = std::min<std::size_t>(off, 777);
        off -= n;
        double* pb[2] = {b0.data() + off, b1.data() + off};
        b.fill(100 + off, n, pb);
    }
    CHECK(a0 == b0);
    CHECK(a1 == b1);
    CHECK(a0 != a1);
    double* pc[2] = {c0.data(), c1.data()};
    c.fill(100, 10000, pc);
    CHECK(a0 != c0);
}
