// Generator: geometry, Lissajous error signatures (MODEL.md 2.5 table), ADC, determinism.
#include "signal_gen/analysis.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/generator.hpp"
#include "signal_gen/optics.hpp"
#include "helpers.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <random>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_generator_cpp {

using namespace fringe;
using Catch::Matchers::WithinAbs;
using Catch::Matchers::WithinRel;

namespace {
// Phase error of an uncorrected atan2 against truth, fitted on harmonics of theta.
HarmonicFit atan2_error_harmonics(const Block& b, int K = 4) {
    std::vector<double> ph = test::atan2_phase(b);
    std::vector<double> e(b.size());
    const double shift = kTwoPi * std::round((ph[0] - b.theta_rad[0]) / kTwoPi);
    for (std::size_t i = 0; i < b.size(); ++i) e[i] = ph[i] - shift - b.theta_rad[i];
    return fit_harmonics(e.data(), b.theta_rad.data(), b.size(), K);
}
}  // namespace

TEST_CASE("disc eccentricity is a once-per-rev phase modulation of amplitude n*e1/r", "[generator]") {
    EncoderProfile e = test::clean_ideal(64);
    e.e1_cm = 0.002;
    e.e1_phase_rad = 0.7;
    MotionProfile m;
    m.kind = MotionKind::Constant;
    m.velocity_rad_s = kTwoPi;  // one rev per second
    Block b = test::generate(e, m, 20000, 20000);
    // Demodulate the signals (not the truth): theta - n*phi from atan2, fitted on phi.
    std::vector<double> ph = test::atan2_phase(b), dev(b.size());
    for (std::size_t i = 0; i < b.size(); ++i) dev[i] = ph[i] - 64 * b.phi_rad[i];
    HarmonicFit f = fit_harmonics(dev.data(), b.phi_rad.data(), b.size(), 3);
    CHECK_THAT(f.amplitude[0], WithinRel(64 * 0.002 / 2.5, 1e-9));
    // phase: dev = A sin(phi + psi) = A cos(psi) sin(phi) + A sin(psi) cos(phi)
    CHECK_THAT(std::atan2(f.cos_coef[0], f.sin_coef[0]), WithinAbs(0.7, 1e-9));
    CHECK(f.amplitude[1] < 1e-9);
    // Truth rate is d(theta)/dt: compare with a central difference of the truth phase.
    for (std::size_t i = 1; i + 1 < b.size(); i += 997)
        CHECK_THAT(b.omega_rad_s[i], WithinRel((b.theta_rad[i + 1] - b.theta_rad[i - 1]) * 10000, 1e-6));
}

TEST_CASE("gap run-out modulates the amplitude once per revolution", "[generator]") {
    EncoderProfile e = test::clean_diffraction(1.0, 2.871);
    e.lines_per_rev = 32;
    e.gap_d1_cm = 0.747;
    e.gap_d2_cm = 0.670;
    MotionProfile m;
    m.kind = MotionKind::Constant;
    m.velocity_rad_s = kTwoPi;
    Block b = test::generate(e, m, 64000, 64000);
    // Envelope sqrt(s^2 + c^2) of the fundamental ranges between the d1 and d2 amplitudes.
    double lo = 1e9, hi = 0;
    for (double phi = 0; phi < kTwoPi; phi += 0.01) {
        const double D = 0.5 * (0.747 + 0.670) + 0.5 * (0.747 - 0.670) * std::cos(phi);
        const double a = optics::fundamental_amplitude(0.747 / D, 2.871);
        lo = std::min(lo, a);
        hi = std::max(hi, a);
    }
    CHECK_THAT(lo, WithinAbs(0.991, 5e-4));
    CHECK_THAT(hi, WithinAbs(1.093, 5e-4));
    // The generated fundamental over the first and the middle line (phi ~ 0: D = d1; phi ~ pi: D = d2).
    auto amp_near = [&](double phi_centre) {
        std::vector<double> s, th;
        for (std::size_t i = 0; i < b.size(); ++i)
            if (std::fabs(b.phi_rad[i] - phi_centre) < kTwoPi / 32 / 2) { s.push_back(b.sin_v[i]); th.push_back(b.theta_rad[i]); }
        return fit_harmonics(s.data(), th.data(), s.size(), 3).amplitude[0];
    };
    CHECK_THAT(amp_near(kTwoPi / 64), WithinAbs(0.991, 0.002));
    CHECK_THAT(amp_near(kPi), WithinAbs(1.093, 0.002));
}

TEST_CASE("Lissajous errors give their known phase-error harmonics", "[generator]") {
    const double A = 1.0;
    MotionProfile m = test::constant_electrical(50.0, 1024);
    SECTION("offsets -> 1x of amplitude |o|/A") {
        EncoderProfile e = test::clean_ideal();
        e.lissajous.offset_sin_v = 0.004;
        e.lissajous.offset_cos_v = -0.003;
        HarmonicFit f = atan2_error_harmonics(test::generate(e, m, 1e5, 20000));
        // (o_s cos(theta) - o_c sin(theta))/A, to first order
        CHECK_THAT(f.cos_coef[0], WithinAbs(0.004 / A, 2e-5));
        CHECK_THAT(f.sin_coef[0], WithinAbs(0.003 / A, 2e-5));
        CHECK(f.amplitude[1] < 2e-5);
    }
    SECTION("gain mismatch -> 2x of amplitude eps/2") {
        EncoderProfile e = test::clean_ideal();
        e.lissajous.gain_mismatch = 0.01;
        HarmonicFit f = atan2_error_harmonics(test::generate(e, m, 1e5, 20000));
        CHECK_THAT(f.sin_coef[1], WithinAbs(0.005, 3e-5));
        CHECK(f.amplitude[0] < 1e-9);
        CHECK(std::fabs(f.cos_coef[1]) < 1e-6);
    }
    SECTION("quadrature error -> mean delta/2 and 2x of -delta/2 cos") {
        EncoderProfile e = test::clean_ideal();
        e.lissajous.quadrature_error_rad = 0.01;
        HarmonicFit f = atan2_error_harmonics(test::generate(e, m, 1e5, 20000));
        CHECK_THAT(f.dc, WithinAbs(0.005, 3e-5));
        CHECK_THAT(f.cos_coef[1], WithinAbs(-0.005, 3e-5));
    }
    SECTION("common 3rd harmonic h3 -> 4x of amplitude h3") {
        EncoderProfile e = test::clean_ideal();
        e.harmonics.push_back({3, 0.01, 0.0});
        HarmonicFit f = atan2_error_harmonics(test::generate(e, m, 1e5, 20000), 6);
        CHECK_THAT(f.amplitude[3], WithinAbs(0.01, 2e-4));
        CHECK(f.amplitude[1] < 1e-6);
    }
    SECTION("common 2nd harmonic h2 -> 1x and 3x, each h2/sqrt(2)") {
        EncoderProfile e = test::clean_ideal();
        e.harmonics.push_back({2, 0.01, 0.0});
        HarmonicFit f = atan2_error_harmonics(test::generate(e, m, 1e5, 20000), 6);
        CHECK_THAT(f.amplitude[0], WithinAbs(0.01 / std::sqrt(2.0), 2e-4));
        CHECK_THAT(f.amplitude[2], WithinAbs(0.01 / std::sqrt(2.0), 2e-4));
    }
}

TEST_CASE("ADC quantiser: mid-tread, step, clipping", "[generator][adc]") {
    Quantizer q{10, -1.25, 1.25};
    const double step = 2.5 / 1024;
    CHECK(q.step_v() == step);
    CHECK(q.apply(0.0) == 0.0);                  // mid-tread: zero is a level
    CHECK(q.apply(0.49 * step) == 0.0);
    CHECK(q.apply(0.51 * step) == step);
    CHECK(q.apply(-0.51 * step) == -step);
    CHECK(q.apply(5.0) == -1.25 + 1023 * step);  // clipped at the top code
    CHECK(q.apply(-5.0) == -1.25);
    CHECK(q.clips(1.3));
    CHECK_FALSE(q.clips(1.2));
    // Error within +-q/2 everywhere inside the range, uniform: variance q^2/12.
    double sum2 = 0;
    const int N = 100000;
    for (int i = 0; i < N; ++i) {
        double v = -1.2 + 2.4 * (i + 0.5) / N;
        double e = q.apply(v) - v;
        REQUIRE(std::fabs(e) <= step / 2 + 1e-15);
        sum2 += e * e;
    }
    CHECK_THAT(sum2 / N, WithinRel(step * step / 12, 0.01));
}

TEST_CASE("the generator quantises through the profile's ADC", "[generator][adc]") {
    EncoderProfile e = test::clean_ideal();
    e.adc = Quantizer{12, -1.25, 1.25};
    Block b = test::generate(e, test::constant_electrical(100, 1024), 1e5, 5000);
    const double step = 2.5 / 4096;
    for (std::size_t i = 0; i < b.size(); ++i) {
        double code = (b.sin_v[i] + 1.25) / step;
        REQUIRE(std::fabs(code - std::round(code)) < 1e-9);
        REQUIRE(std::fabs(b.sin_v[i] - std::sin(b.theta_rad[i])) <= step / 2 + 1e-12);
    }
}

TEST_CASE("same seed, same output, and any block partition gives the same output", "[generator][determinism]") {
    EncoderProfile e = test::clean_diffraction(1.1149, 2.8713);
    e.noise = {2e-4, 1e-4, 0.03, 2.0, 0.0};
    e.adc = Quantizer{16, -1.25, 1.25};
    e.e1_cm = 0.001;
    e.gap_d2_cm = 0.70;
    MotionProfile m = test::constant_electrical(106.7, 1024);
    const std::size_t N = 3 * kNoiseChunk + 123;
    Block whole = test::generate(e, m, 1e5, N, 42);
    Block again = test::generate(e, m, 1e5, N, 42);
    CHECK(whole.sin_v == again.sin_v);
    CHECK(whole.cos_v == again.cos_v);
    Block other = test::generate(e, m, 1e5, N, 43);
    CHECK(whole.sin_v != other.sin_v);

    Generator g(e, m, 1e5, 42);
    std::mt19937 rng(7);
    std::vector<double> s, c, th;
    for (std::size_t k = 0; k < N;) {
        std::size_t n = std::min<std::size_t>(N - k, 1 + rng() % 3000);
        Block b;
        b.resize(n, false);
        g.generate(k, b);
        s.insert(s.end(), b.sin_v.begin(), b.sin_v.end());
        c.insert(c.end(), b.cos_v.begin(), b.cos_v.end());
        th.insert(th.end(), b.theta_rad.begin(), b.theta_rad.end());
        k += n;
    }
    CHECK(s == whole.sin_v);
    CHECK(c == whole.cos_v);
    CHECK(th == whole.theta_rad);
    // Random access: a block starting mid-chunk equals the same slice.
    Block mid;
    mid.resize(500, false);
    g.generate(5000, mid);
    CHECK(std::equal(mid.sin_v.begin(), mid.sin_v.end(), whole.sin_v.begin() + 5000));
}

TEST_CASE("noise levels: additive sigma per channel, gain noise scales the raw signal", "[generator][noise]") {
    EncoderProfile e = test::clean_diffraction(1.1149, 2.8713);
    MotionProfile m = test::constant_electrical(106.7, 1024);
    const std::size_t N = 200000;
    Block clean = test::generate(e, m, 1e5, N);
    e.noise.sigma_add_v = 3e-4;
    Block noisy = test::generate(e, m, 1e5, N);
    double ss = 0, sc = 0, cross = 0;
    for (std::size_t i = 0; i < N; ++i) {
        double a = noisy.sin_v[i] - clean.sin_v[i], b = noisy.cos_v[i] - clean.cos_v[i];
        ss += a * a; sc += b * b; cross += a * b;
    }
    CHECK_THAT(std::sqrt(ss / N), WithinRel(3e-4, 0.01));
    CHECK_THAT(std::sqrt(sc / N), WithinRel(3e-4, 0.01));
    // Independent channels: the sample covariance is within 5 sigma (sigma^2/sqrt(N)) of zero.
    CHECK(std::fabs(cross / N) < 5 * 9e-8 / std::sqrt(double(N)));

    // Gain noise: deviation = sigma_g * g_noise * V_raw (V_raw includes the DC pedestal Vmax*w/2).
    e.noise = {};
    e.noise.sigma_gain = 1e-3;
    Block g = test::generate(e, m, 1e5, N);
    double num = 0, den = 0;
    for (std::size_t i = 0; i < N; ++i) {
        double raw = clean.sin_v[i] + e.reference_v();
        double d = g.sin_v[i] - clean.sin_v[i];
        num += d * d;
        den += raw * raw;
    }
    CHECK_THAT(std::sqrt(num / den), WithinRel(1e-3, 0.01));
}

TEST_CASE("reference mark: one pulse per revolution of the configured width", "[generator][index]") {
    EncoderProfile e = test::clean_ideal(100);
    e.index.enabled = true;
    e.index.position_rad = 1.0;
    e.index.width_elec_rad = kTwoPi;  // one line
    MotionProfile m;
    m.kind = MotionKind::Constant;
    m.velocity_rad_s = kTwoPi * 2;  // 2 rev/s
    const double fs = 1e6;
    Block b = test::generate(e, m, fs, 1000000);  // 1 s: 2 revolutions
    int rising = 0;
    std::size_t high = 0;
    for (std::size_t i = 0; i < b.size(); ++i) {
        if (b.index_v[i] > 0.5) ++high;
        if (i > 0 && b.index_v[i] > 0.5 && b.index_v[i - 1] < 0.5) {
            ++rising;
            CHECK_THAT(std::fmod(b.phi_rad[i], kTwoPi), WithinAbs(1.0, kTwoPi * 2 / fs));
        }
    }
    CHECK(rising == 2);
    // width: one line = 1/100 rev = 5 ms per pulse at 2 rev/s -> 2 * 5000 samples
    CHECK(std::abs(static_cast<long>(high) - 10000) <= 2);
}

TEST_CASE("fast_sincos agrees with libm to about an ulp over its whole range", "[generator][fastmath]") {
    // glibc's sin/cos are within an ulp of the true values; the generator's vectorised kernel
    // must stay within ~1.5 ulp of them (|value| <= 1, so an absolute 3.4e-16), up to
    // kFastSinCosMaxArg, including arguments next to multiples of pi/2 where the reduction
    // cancels most bits, and must be exactly odd (sin) and even (cos).
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> unit(-1.0, 1.0);
    double worst = 0.0;
    auto check = [&](double x) {
        double s, c, sn, cn;
        fast_sincos(x, s, c);
        fast_sincos(-x, sn, cn);
        worst = std::max({worst, std::fabs(s - std::sin(x)), std::fabs(c - std::cos(x))});
        CHECK(sn == -s);
        CHECK(cn == c);
    };
    for (int i = 0; i < 200000; ++i) check(8.0 * unit(rng));
    for (int i = 0; i < 200000; ++i) check(kFastSinCosMaxArg * unit(rng));
    for (int k = -2000; k <= 2000; ++k)  // next to k*pi/2, near the small and the large end
        for (double base : {0.0, 0.9 * kFastSinCosMaxArg}) {
            const double x = std::nearbyint(base / (kPi / 2) + k) * (kPi / 2);
            for (double d : {0.0, 1e-9, -1e-9}) check(x + d);
        }
    double s0, c0;
    fast_sincos(0.0, s0, c0);
    CHECK(s0 == 0.0);
    CHECK(c0 == 1.0);
    INFO("largest difference from libm " << worst);
    CHECK(worst <= 3.4e-16);
}

}  // namespace test_generator_cpp
