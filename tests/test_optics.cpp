// MODEL.md section 2: closed forms checked against quadrature, the direct slit sum, and the
// duty-cycle table.
#include "signal_gen/analysis.hpp"
#include "signal_gen/fastmath.hpp"
#include "signal_gen/optics.hpp"
#include "helpers.hpp"

#include <boost/math/quadrature/gauss_kronrod.hpp>
#include <catch2/catch.hpp>

#include <cmath>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_optics_cpp {

using namespace fringe;
using Catch::Matchers::WithinAbs;

TEST_CASE("Si matches adaptive quadrature and tabulated values", "[optics]") {
    using boost::math::quadrature::gauss_kronrod;
    auto sinc = [](double t) { return t == 0 ? 1.0 : std::sin(t) / t; };
    for (double x : {0.001, 0.5, 1.0, 1.9, 2.0, 2.1, 5.0, 12.0, 40.0, 150.0}) {
        double err = 0;
        double q = gauss_kronrod<double, 61>::integrate(sinc, 0.0, x, 12, 1e-14, &err);
        CHECK_THAT(optics::sine_integral(x), WithinAbs(q, 1e-13));
        CHECK_THAT(optics::sine_integral(-x), WithinAbs(-q, 1e-13));
    }
    // Abramowitz & Stegun 5.2: Si(1) = 0.946083070367183, Si(10) = 1.658347594218874
    CHECK_THAT(optics::sine_integral(1.0), WithinAbs(0.946083070367183, 1e-14));
    CHECK_THAT(optics::sine_integral(10.0), WithinAbs(1.658347594218874, 1e-14));
    CHECK_THAT(optics::sine_integral(1e6), WithinAbs(kPi / 2, 2e-6));
}

TEST_CASE("Phi(u) = Si(2u) - sin^2(u)/u is the integral of (sin u/u)^2", "[optics]") {
    using boost::math::quadrature::gauss_kronrod;
    auto F = [](double u) { return optics::slit_intensity(u); };
    for (double u : {1e-5, 5e-4, 0.3, 1.0, 3.0, 7.5, 20.0, -2.0}) {
        double q = gauss_kronrod<double, 61>::integrate(F, 0.0, u, 12, 1e-14);
        CHECK_THAT(optics::slit_integral(u), WithinAbs(q, 1e-13));
    }
    // Total power: integral of F over the line is pi.
    CHECK_THAT(2 * optics::slit_integral(1e9), WithinAbs(kPi, 1e-8));
}

TEST_CASE("Fourier closed form equals the direct slit sum", "[optics]") {
    // 2*kappa kept away from integers, where the direct sum's oscillating tail does not
    // cancel (see optics.hpp); kappa = 1.1149 is the paper's d2.
    const double kappa = GENERATE(0.8, 1.1149, 1.3, 1.7, 2.3);
    const double w = GENERATE(0.5, 2.8713, 4.0);
    for (double c = -3.0; c < 3.2; c += 0.9) {
        INFO("kappa " << kappa << " w " << w << " centre " << c);
        CHECK_THAT(optics::aperture_fourier(c, kappa, w), WithinAbs(optics::aperture_slit_sum(c, kappa, w, 2000, 100000), 1e-9));
    }
}

TEST_CASE("duty-cycle table of MODEL.md 2.3 at kappa = 1.1149", "[optics]") {
    // Comparator at the mid level (max+min)/2 of the sin channel, over one dense period.
    // Tolerance: half a unit in the table's last printed digit, plus a little margin.
    struct Row { double w, duty_error, tol; };
    const Row rows[] = {{0.5, 0.105, 6e-4}, {2.0, 0.062, 6e-4}, {2.5, 0.037, 6e-4},
                        {2.871, 0.0160, 6e-5}, {kPi, 0.0, 1e-5}, {3.3, -0.0094, 6e-5}};
    const double kappa = 0.747 / 0.670;
    for (const Row& r : rows) {
        const int N = 200000;
        std::vector<double> v(N);
        for (int i = 0; i < N; ++i) v[i] = optics::aperture_fourier(kTwoPi * i / N - kPi / 2, kappa, r.w);
        double err = 0.5 - duty_cycle(v.data(), v.size());
        INFO("w = " << r.w);
        CHECK_THAT(err, WithinAbs(r.duty_error, r.tol));
    }
}

TEST_CASE("fundamental amplitude and its gap dependence", "[optics]") {
    // MODEL.md 2.2: 2*Vmax*(1 - 1/(2 kappa)) sin(w/2); d1 -> d2 raises it ~10 % (0.991 -> 1.093 V).
    const double w = 2.871;
    CHECK_THAT(optics::fundamental_amplitude(1.0, w), WithinAbs(0.991, 0.0005));
    CHECK_THAT(optics::fundamental_amplitude(0.747 / 0.670, w), WithinAbs(1.093, 0.0005));
    // The generator's sin channel, noise-free, fitted on the true phase.
    for (double gap : {0.747, 0.70, 0.670}) {
        EncoderProfile e = test::clean_diffraction(1.0, w);
        e.gap_d1_cm = e.gap_d2_cm = gap;
        Block b = test::generate(e, test::constant_electrical(100.0, e.lines_per_rev), 1e5, 2000);
        HarmonicFit f = fit_harmonics(b.sin_v.data(), b.theta_rad.data(), b.size(), 4);
        const double kappa = 0.747 / gap;
        CHECK_THAT(f.amplitude[0], WithinAbs(2 * (1 - 1 / (2 * kappa)) * std::sin(w / 2), 1e-12));
        CHECK_THAT(f.dc, WithinAbs(0.0, 1e-12));  // front end removes Vmax*w/2 exactly
    }
}

TEST_CASE("kappa <= 1 gives a pure sinusoid for any aperture", "[optics]") {
    const double kappa = GENERATE(0.5, 0.9, 1.0);
    const double w = GENERATE(0.3, 1.7, 2.8713, 5.0);
    EncoderProfile e = test::clean_diffraction(kappa, w);
    Block b = test::generate(e, test::constant_electrical(100.0, e.lines_per_rev), 1e5, 3000);
    HarmonicFit f = fit_harmonics(b.sin_v.data(), b.theta_rad.data(), b.size(), 6);
    for (int k = 2; k <= 6; ++k) CHECK(f.amplitude[k - 1] < 1e-12);
    // and the sin channel is exactly A*sin(theta)
    CHECK_THAT(f.sin_coef[0], WithinAbs(optics::fundamental_amplitude(kappa, w), 1e-12));
    CHECK_THAT(f.cos_coef[0], WithinAbs(0.0, 1e-12));
}

TEST_CASE("2nd harmonic for 1 < kappa <= 1.5 follows h2 = (kappa-1)/(kappa-1/2) cos(w/2)", "[optics]") {
    const double kappa = GENERATE(1.05, 1.1149, 1.3, 1.5);
    const double w = GENERATE(1.0, 2.8713, 3.5);
    EncoderProfile e = test::clean_diffraction(kappa, w);
    Block b = test::generate(e, test::constant_electrical(100.0, e.lines_per_rev), 1e5, 3000);
    HarmonicFit f = fit_harmonics(b.cos_v.data(), b.theta_rad.data(), b.size(), 4);
    const double h2 = (kappa - 1) / (kappa - 0.5) * std::cos(w / 2);
    CHECK_THAT(f.cos_coef[1] / f.cos_coef[0], WithinAbs(h2, 1e-12));
    CHECK(f.amplitude[2] < 1e-12);  // no 3rd harmonic below kappa = 1.5
    if (kappa == 1.1149 && w == 2.8713) CHECK_THAT(std::fabs(h2), WithinAbs(0.0252, 0.0001));
}

}  // namespace test_optics_cpp
