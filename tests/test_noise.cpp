// The normal generator against the normal distribution's analytic moments and tails.
#include "signal_gen/noise.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <vector>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_noise_cpp {

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

TEST_CASE("noise field: each stream is N(0,1), streams uncorrelated, view equals fill", "[noise]") {
    // The generator's path: counter-based bits, the ziggurat's branch-free fast path and the
    // ~1 % of missed draws finished separately (those carry the wedges and the tail beyond R).
    NoiseField f(2024, 1, 3);
    const std::size_t N = 1u << 22;
    std::vector<double> s0(N), s1(N), s2(N);
    double* p[3] = {s0.data(), s1.data(), s2.data()};
    f.fill(0, N, p);
    for (const auto* v : {&s0, &s1, &s2}) {
        double m1 = 0, m2 = 0, m4 = 0;
        long beyond2 = 0, beyond_r = 0, beyond4 = 0;
        for (double x : *v) {
            m1 += x; m2 += x * x; m4 += x * x * x * x;
            const double a = std::fabs(x);
            beyond2 += a > 2; beyond_r += a > 3.442619855899; beyond4 += a > 4;
        }
        m1 /= N; m2 /= N; m4 /= N;
        CHECK_THAT(m1, WithinAbs(0.0, 5 / std::sqrt(double(N))));
        CHECK_THAT(m2, WithinAbs(1.0, 5 * std::sqrt(2.0 / N)));
        CHECK_THAT(m4, WithinAbs(3.0, 5 * std::sqrt(96.0 / N)));
        for (auto [count, z] : {std::pair{beyond2, 2.0}, {beyond_r, 3.442619855899}, {beyond4, 4.0}}) {
            const double pz = std::erfc(z / std::sqrt(2.0));
            CHECK_THAT(double(count) / N, WithinAbs(pz, 5 * std::sqrt(pz * (1 - pz) / N)));
        }
    }
    double c01 = 0, c02 = 0, c12 = 0, lag1 = 0;
    for (std::size_t i = 0; i < N; ++i) {
        c01 += s0[i] * s1[i]; c02 += s0[i] * s2[i]; c12 += s1[i] * s2[i];
        if (i) lag1 += s0[i] * s0[i - 1];
    }
    const double lim = 5 / std::sqrt(double(N));
    CHECK(std::fabs(c01 / N) < lim);
    CHECK(std::fabs(c02 / N) < lim);
    CHECK(std::fabs(c12 / N) < lim);
    CHECK(std::fabs(lag1 / N) < lim);

    // A range inside one chunk is served without a copy; one across chunks is not.
    const double* v[3];
    REQUIRE(f.view(kNoiseChunk + 100, 1000, v));
    for (int s = 0; s < 3; ++s)
        CHECK(std::equal(v[s], v[s] + 1000, (s == 0 ? s0 : s == 1 ? s1 : s2).begin() + kNoiseChunk + 100));
    CHECK_FALSE(f.view(kNoiseChunk - 10, 20, v));
}

TEST_CASE("fill_normals: the vectorised fast path gives exactly the portable path's numbers", "[noise]") {
    // Where the build has AVX-512 the two paths differ in code; elsewhere this is trivially true.
    for (std::uint64_t key : {0ULL, 1ULL, 0x9e3779b97f4a7c15ULL, ~0ULL}) {
        for (std::size_t n : {std::size_t{1}, std::size_t{7}, std::size_t{8}, std::size_t{13}, kNoiseChunk * 3}) {
            std::vector<double> a(n), b(n);
            std::vector<std::uint32_t> scratch(n);
            fill_normals(key, n, a.data(), scratch.data());
            fill_normals(key, n, b.data(), scratch.data(), true);
            INFO("key " << key << " n " << n);
            CHECK(a == b);
        }
    }
}

namespace {
// The ziggurat of noise.cpp with its wedge decided by exp() alone (no squeeze): the tables
// rebuilt from their definition (Marsaglia & Tsang's 128 layers, Doornik's layout), the same
// draws consumed in the same order.
struct RefZiggurat {
    static constexpr int L = 128;
    static constexpr double R = 3.442619855899, V = 9.91256303526217e-3;
    double x[L + 1], ratio[L], f[L + 1];
    RefZiggurat() {
        double fr = std::exp(-0.5 * R * R);
        x[0] = V / fr;
        x[1] = R;
        x[L] = 0.0;
        for (int i = 2; i < L; ++i) {
            x[i] = std::sqrt(-2.0 * std::log(V / x[i - 1] + fr));
            fr = std::exp(-0.5 * x[i] * x[i]);
        }
        for (int i = 0; i < L; ++i) ratio[i] = x[i + 1] / x[i];
        for (int i = 0; i <= L; ++i) f[i] = std::exp(-0.5 * x[i] * x[i]);
    }
    static double uniform(std::uint64_t b) { return (static_cast<double>(b >> 11) + 1.0) * 0x1p-53; }
    double operator()(Xoshiro256pp& rng) const {
        for (;;) {
            const std::uint64_t bits = rng.next();
            const auto i = bits & (L - 1);
            const double u = static_cast<double>(static_cast<std::int64_t>(bits >> 11)) * 0x1p-52 - 1.0;
            if (std::fabs(u) < ratio[i]) return u * x[i];
            if (i == 0) {
                double a, b;
                do {
                    a = std::log(uniform(rng.next())) / R;
                    b = std::log(uniform(rng.next()));
                } while (-2.0 * b < a * a);
                return u < 0 ? a - R : R - a;
            }
            const double v = u * x[i];
            if (f[i] + uniform(rng.next()) * (f[i + 1] - f[i]) < std::exp(-0.5 * v * v)) return v;
        }
    }
};
}  // namespace

TEST_CASE("the ziggurat's squeeze decides every wedge as the exact test does", "[noise]") {
    // 4e6 draws: about 1e5 reach a wedge (the squeeze's chord and tangent bounds decide most of
    // them without exp); every number, and the generator's state after them, must be the
    // exact test's.
    const RefZiggurat ref;
    for (std::uint64_t seed : {1ULL, 2ULL, 0xfeedULL, 1234567ULL}) {
        Xoshiro256pp a(seed), b(seed);
        for (int i = 0; i < 1000000; ++i) REQUIRE(standard_normal(a) == ref(b));
        CHECK(a.next() == b.next());
    }
}
}  // namespace test_noise_cpp
