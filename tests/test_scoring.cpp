// Scoring conventions (MODEL.md 7) and bounds (MODEL.md 6) against closed forms.
#include "helpers.hpp"

#include "server/analysis/bounds.hpp"
#include "server/engine/scenario.hpp"
#include "server/analysis/scoring.hpp"
#include "signal_gen/fastmath.hpp"

#include <catch2/catch.hpp>

#include <Eigen/Dense>

#include <random>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_scoring_cpp {

using namespace fringe;

namespace {
struct Synthetic {
    std::vector<double> t, th, om, est;
    std::vector<std::uint8_t> valid;
};
// theta_true = w*t; estimate = truth + e(t) with a known error function.
template <class F>
Synthetic make(std::size_t n, double fs, double w, F err) {
    Synthetic s;
    for (std::size_t i = 0; i < n; ++i) {
        const double t = static_cast<double>(i) / fs;
        s.t.push_back(t);
        s.th.push_back(w * t);
        s.om.push_back(w);
        s.est.push_back(w * t + err(w * t, i));
        s.valid.push_back(1);
    }
    return s;
}
ErrorMetrics score(const Synthetic& s, double settle) {
    Scorer sc(settle);
    // feed in uneven blocks: the result must not depend on them
    std::size_t i = 0, m = 1;
    while (i < s.t.size()) {
        const std::size_t k = std::min(m, s.t.size() - i);
        sc.add(k, &s.t[i], &s.th[i], &s.om[i], &s.est[i], nullptr, &s.valid[i]);
        i += k;
        m = m * 3 + 1;
    }
    return sc.finish();
}
}  // namespace

TEST_CASE("scorer: moments, harmonics and the removed 2*pi multiple", "[scoring]") {
    const double a = 2e-3, b = 5e-4, phi = 0.7;
    auto s = make(200000, 1e5, 500.0, [&](double th, std::size_t) { return 4 * kTwoPi + a + b * std::cos(3 * th - phi); });
    const auto m = score(s, 0.0);
    CHECK(m.removed_cycles == 4.0);
    CHECK(m.mean_rad == Approx(a).epsilon(1e-3));
    CHECK(m.std_rad == Approx(b / std::sqrt(2.0)).epsilon(1e-3));
    CHECK(m.rms_rad == Approx(std::sqrt(a * a + b * b / 2)).epsilon(1e-3));
    CHECK(m.max_abs_rad == Approx(a + b).epsilon(1e-6));
    CHECK(m.max_dev_rad == Approx(b).epsilon(1e-3));
    REQUIRE(m.harmonics.size() == 16);  // 1x..16x by default
    CHECK(m.harmonics[2].amplitude_rad == Approx(b).epsilon(1e-9));
    CHECK(m.harmonics[2].phase_rad == Approx(phi).epsilon(1e-9));
    CHECK(m.harmonics[0].amplitude_rad < 1e-12);
    CHECK(m.harmonics[5].amplitude_rad < 1e-12);
    CHECK(m.slipped_samples == 0);
    CHECK(*m.lag_s == Approx(-a / 500.0).epsilon(1e-3));
    CHECK(*m.lock_time_s == 0.0);
}

TEST_CASE("scorer: settle time, invalid samples, slips and lock time", "[scoring]") {
    // 0..0.1 s: 1 rad error (not locked); then small; a 2*pi slip for the last 1000 samples.
    auto s = make(100000, 1e5, 300.0, [&](double, std::size_t i) {
        if (i < 10000) return 1.0;
        return i >= 99000 ? kTwoPi + 1e-4 : 1e-4;
    });
    for (std::size_t i = 50000; i < 50010; ++i) s.valid[i] = 0;
    const auto m = score(s, 0.05);
    CHECK(m.samples == 100000);
    CHECK(m.invalid_after_settle == 10);
    CHECK(m.scored == 100000 - 5000 - 10);
    CHECK(m.removed_cycles == 0.0);
    CHECK(m.slipped_samples == 1000);  // the 1-rad start is no slip (|e| < pi); the 2*pi jump is
    REQUIRE(m.lock_time_s);
    CHECK(*m.lock_time_s == Approx(0.5001).epsilon(1e-9));  // after the last invalid sample
}

TEST_CASE("per-sample information: A^2/sigma^2 for ideal quadrature, half for sin only", "[bounds]") {
    auto e = test::clean_ideal(1024);
    e.vmax_v = 0.8;
    e.noise.sigma_add_v = 1e-3;
    auto both = signal_information(e, 3);
    REQUIRE(both);
    CHECK(both->j_mean == Approx(0.64e6).epsilon(1e-8));
    CHECK(both->j_min == Approx(0.64e6).epsilon(1e-8));
    CHECK(both->j_max == Approx(0.64e6).epsilon(1e-8));
    auto sin_only = signal_information(e, 1);
    CHECK(sin_only->j_mean == Approx(0.32e6).epsilon(1e-8));
    CHECK(sin_only->j_min < 1e-4 * sin_only->j_mean);  // zero at the sin peaks
    // quantisation adds q^2/12
    e.adc.bits = 10;
    const double q = 2.5 / 1024;
    CHECK(signal_information(e, 3)->j_mean == Approx(0.64 / (1e-6 + q * q / 12)).epsilon(1e-8));
    // no noise at all: no bound
    e.adc.bits = 0;
    e.noise.sigma_add_v = 0;
    CHECK_FALSE(signal_information(e, 3));
}

TEST_CASE("per-sample information on the 1.6 % duty-cycle signal spans MODEL.md's range", "[bounds]") {
    const auto sc = load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/paper-duty1p6.json");
    const auto j = signal_information(sc.encoder, 3);
    REQUIRE(j);
    INFO("J min " << j->j_min << " mean " << j->j_mean << " max " << j->j_max);
    // MODEL.md 6 quotes 1.5e7-2.1e7 with a scalar sigma_eff ~ 2.6e-4 V. With the correlated
    // gain-noise term sigma_g^2 v v' the information is higher where h' is orthogonal to v,
    // up to |h'|^2/sigma^2 ~ 3.4e7; the minimum and the mean (which sets the ~2e-5 rad
    // tracking bound at fn = 100 Hz, MODEL.md 4.3) agree with MODEL.md.
    CHECK(j->j_min == Approx(1.5e7).epsilon(0.1));
    CHECK(j->j_mean == Approx(2.2e7).epsilon(0.1));
    CHECK(j->j_max < 3.6e7);
}

TEST_CASE("tracking bound: DARE solver against Kalata's closed form and the continuous limits", "[bounds]") {
    const double T = 1e-5, r = 4e-8;
    SECTION("discrete white-noise acceleration: Kalata, to rounding") {
        const double sigma_a2 = GENERATE(1e2, 1e6, 1e9);
        Eigen::MatrixXd F(2, 2), Q(2, 2);
        F << 1, T, 0, 1;
        Eigen::Vector2d G(T * T / 2, T);
        Q = sigma_a2 * G * G.transpose();
        const auto d = steady_state_bound(F, Q, r);
        const auto k = kalata_cv(sigma_a2, r, T);
        CHECK(d.pcrb_rad2 == Approx(k.pcrb_rad2).epsilon(1e-9));
        CHECK(d.pcrb_omega_rad2_s2 == Approx(k.pcrb_omega_rad2_s2).epsilon(1e-8));
        CHECK(d.gain_theta == Approx(k.gain_theta).epsilon(1e-9));
        CHECK(d.gain_omega_per_s == Approx(k.gain_omega_per_s).epsilon(1e-8));
    }
    SECTION("CV continuous limit: P11 = sqrt(2) wn N, noise-only 0.75 P11") {
        const double wn = kTwoPi * 20, N = r * T, q = std::pow(wn, 4) * N;
        const auto b = tracking_bound(est::Kinematics::CV, q, r, T);
        CHECK(b.pcrb_rad2 == Approx(std::sqrt(2.0) * wn * N).epsilon(0.01));
        CHECK(b.pcrb_omega_rad2_s2 == Approx(std::sqrt(2.0) * std::pow(wn, 3) * N).epsilon(0.01));
        CHECK(b.noise_only_rad2 / b.pcrb_rad2 == Approx(0.75).epsilon(0.01));
        CHECK(b.gain_theta == Approx(std::sqrt(2.0) * wn * T).epsilon(0.01));
    }
    SECTION("CA continuous limit: P11 = 2 wn N, noise-only 5/3 wn N") {
        const double wn = kTwoPi * 20, N = r * T, q = std::pow(wn, 6) * N;
        const auto b = tracking_bound(est::Kinematics::CA, q, r, T);
        CHECK(b.pcrb_rad2 == Approx(2 * wn * N).epsilon(0.01));
        CHECK(b.noise_only_rad2 == Approx(5.0 / 3.0 * wn * N).epsilon(0.02));
    }
}

TEST_CASE("scorer: the broadband rest is the least-squares residual over a non-integer number of cycles", "[scoring]") {
    // Strong 1x and 3x harmonics plus white noise over 7.37 electrical cycles: the harmonics are
    // not orthogonal over that span, so var - sum(A_k^2)/2 is not the residual.
    std::mt19937_64 rng(11);
    std::normal_distribution<double> noise(0.0, 2e-4);
    const double fs = 10000, w = kTwoPi * 50;  // 200 samples per cycle
    const std::size_t n = static_cast<std::size_t>(7.37 * 200);
    std::vector<double> e_true(n);
    const Synthetic s = make(n, fs, w, [&](double th, std::size_t i) {
        const double e = 3e-3 * std::cos(th - 0.4) + 1e-3 * std::cos(3 * th + 1.1) + 5e-4 + noise(rng);
        e_true[i] = e;
        return e;
    });
    Scorer sc(ScoringOptions{0.0, 0.1, 4});
    sc.add(n, s.t.data(), s.th.data(), s.om.data(), s.est.data(), nullptr, s.valid.data());
    const ErrorMetrics m = sc.finish();
    REQUIRE(m.harmonics.size() == 4);
    // The independent fit: QR on the samples themselves, columns 1, cos k th, sin k th (k = 1..4).
    Eigen::MatrixXd A(n, 9);
    Eigen::VectorXd y(n);
    for (std::size_t i = 0; i < n; ++i) {
        A(i, 0) = 1;
        for (int k = 1; k <= 4; ++k) { A(i, 2 * k - 1) = std::cos(k * s.th[i]); A(i, 2 * k) = std::sin(k * s.th[i]); }
        y(i) = e_true[i];
    }
    const Eigen::VectorXd b = A.colPivHouseholderQr().solve(y);
    const Eigen::VectorXd r = y - A * b;
    const double resid_rms = std::sqrt(r.squaredNorm() / static_cast<double>(n));
    const double var = (y.array() - y.mean()).square().sum();
    CHECK(m.broadband_rms_rad == Approx(resid_rms).epsilon(1e-6));
    CHECK(m.harmonic_power_fraction == Approx(1.0 - r.squaredNorm() / var).epsilon(1e-9));
    CHECK(m.broadband_rms_rad == Approx(2e-4).epsilon(0.1));  // the noise it was made of
    CHECK(m.harmonics[0].amplitude_rad == Approx(std::hypot(b(1), b(2))).epsilon(1e-9));
}

TEST_CASE("output conventions: radians wrapped, degrees, and degrees wrapped either way are named", "[scoring]") {
    const std::size_t n = 20000;
    const double fs = 100000, w = kTwoPi * 137;  // 730 samples per cycle
    auto run = [&](auto out) {
        ConventionCheck c;
        std::vector<double> th(n), hat(n);
        std::vector<std::uint8_t> ok(n, 1);
        for (std::size_t i = 0; i < n; ++i) {
            th[i] = 5.0 + w * static_cast<double>(i) / fs;
            hat[i] = out(th[i] + 1e-4 * std::sin(0.37 * static_cast<double>(i)));
        }
        c.add(n, th.data(), hat.data(), ok.data());
        return c.findings();
    };
    const double deg = 180.0 / kPi;
    auto code = [](const std::vector<ConventionCheck::Finding>& f) { return f.empty() ? std::string("none") : f[0].code; };
    CHECK(code(run([](double x) { return x; })) == "none");
    CHECK(code(run([](double x) { return std::remainder(x, kTwoPi); })) == "estimates_wrapped");
    CHECK(code(run([&](double x) { return x * deg; })) == "estimates_in_degrees");
    const auto wrapped360 = run([&](double x) { const double d = std::fmod(x * deg, 360.0); return d < 0 ? d + 360 : d; });
    CHECK(code(wrapped360) == "estimates_in_degrees_wrapped");
    CHECK_THAT(wrapped360[0].message, Catch::Contains("[0, 360)"));
    const auto wrapped180 = run([&](double x) { return std::remainder(x * deg, 360.0); });
    CHECK(code(wrapped180) == "estimates_in_degrees_wrapped");
    CHECK_THAT(wrapped180[0].message, Catch::Contains("(-180, 180]"));
    // Backwards motion too.
    CHECK(code(run([&](double x) { return std::remainder(-x * deg, 360.0); })) != "none");
}

TEST_CASE("uncertainty: the correlation time and the 95 % intervals against closed forms", "[scoring][uncertainty]") {
    const double fs = 100000, w = kTwoPi * 100;
    SECTION("white noise: tau = 1, and the rms interval covers the true sigma 95 % of the time") {
        int covered_rms = 0, covered_mean = 0, covered_std = 0, trials = 200;
        double tau_sum = 0;
        for (int seed = 0; seed < trials; ++seed) {
            std::mt19937_64 rng(static_cast<std::uint64_t>(seed) + 100);
            std::normal_distribution<double> noise(0.0, 1e-3);
            const Synthetic s = make(8192, fs, w, [&](double, std::size_t) { return noise(rng); });
            Scorer sc(ScoringOptions{0.0, 0.1, 1});
            sc.add(s.t.size(), s.t.data(), s.th.data(), s.om.data(), s.est.data(), nullptr, s.valid.data());
            const ErrorMetrics m = sc.finish();
            REQUIRE(m.correlation_samples);
            tau_sum += *m.correlation_samples;
            const auto u = uncertainty_json(m);
            covered_rms += u["rms_rad"][0].get<double>() <= 1e-3 && 1e-3 <= u["rms_rad"][1].get<double>();
            covered_std += u["std_rad"][0].get<double>() <= 1e-3 && 1e-3 <= u["std_rad"][1].get<double>();
            covered_mean += u["mean_rad"][0].get<double>() <= 0 && 0 <= u["mean_rad"][1].get<double>();
        }
        CHECK(tau_sum / trials == Approx(1.0).epsilon(0.15));
        // Binomial(200, 0.95): 95 % of such counts lie in [184, 196]; the clamp tau >= 1 widens a little.
        CHECK(covered_rms >= 180);
        CHECK(covered_std >= 180);
        CHECK(covered_mean >= 180);
        CHECK(covered_mean <= 200);
    }
    SECTION("AR(1) noise: tau = (1 + rho) / (1 - rho), and the mean's interval covers 0 about 95 % of the time") {
        const double rho = 0.9;  // tau = 19 samples
        int covered = 0, trials = 60;
        double tau_sum = 0;
        for (int seed = 0; seed < trials; ++seed) {
            std::mt19937_64 rng(static_cast<std::uint64_t>(seed) + 7000);
            std::normal_distribution<double> noise(0.0, 1e-3);
            double x = 0;
            const Synthetic s = make(32768, fs, w, [&](double, std::size_t) { x = rho * x + noise(rng); return x; });
            Scorer sc(ScoringOptions{0.0, 0.1, 1});
            sc.add(s.t.size(), s.t.data(), s.th.data(), s.om.data(), s.est.data(), nullptr, s.valid.data());
            const ErrorMetrics m = sc.finish();
            REQUIRE(m.correlation_samples);
            tau_sum += *m.correlation_samples;
            const auto u = uncertainty_json(m);
            covered += u["mean_rad"][0].get<double>() <= 0 && 0 <= u["mean_rad"][1].get<double>();
        }
        CHECK(tau_sum / trials == Approx((1 + rho) / (1 - rho)).epsilon(0.15));
        CHECK(covered >= 51);  // 85 %: tau from 32 batches scatters by about 25 %
    }
    SECTION("too little to go on: no interval, and it says why") {
        const Synthetic s = make(200, fs, w, [&](double th, std::size_t) { return 1e-3 * std::cos(th); });
        Scorer sc(0.0);
        sc.add(s.t.size(), s.t.data(), s.th.data(), s.om.data(), s.est.data(), nullptr, s.valid.data());
        const auto u = uncertainty_json(sc.finish());
        CHECK_FALSE(u.contains("rms_rad"));
        CHECK_THAT(u["note"].get<std::string>(), Catch::Contains("correlation time"));
    }
}

TEST_CASE("scorer: an estimate further off than 1e9 rad keeps its error (a constant 1e300 is every sample slipped, never an rms of 0)", "[scoring]") {
    // Removing the nearest whole cycles from 1e300 - theta_true rounds the truth away and
    // leaves exactly 0: a constant output, or a correction file with offset_rad 1e308, scored
    // rms 0 and passed its limits.
    for (const double out_rad : {1e300, -1e20, 1e12}) {
        auto s = make(20000, 1e5, 500.0, [&](double th, std::size_t) { return out_rad - th; });
        const auto m = score(s, 0.0);
        INFO("estimate " << out_rad << " rad: rms " << m.rms_rad << ", removed cycles " << m.removed_cycles);
        CHECK(m.removed_cycles == 0.0);
        CHECK(m.unremoved_error_rad != 0.0);
        CHECK(m.slipped_samples == m.scored);
        CHECK(!(m.rms_rad < 1.0));  // huge or not finite: no limit on rms_rad passes it
        CHECK(to_json(m, 0).contains("cycles_not_removed"));
    }
    // Within the bound the cycles are removed as before, and the error keeps its precision.
    auto s = make(20000, 1e5, 500.0, [&](double, std::size_t) { return kTwoPi * 1.5e8 + 1e-3; });
    const auto m = score(s, 0.0);
    CHECK(m.removed_cycles == 1.5e8);
    CHECK(m.mean_rad == Approx(1e-3).margin(1e-6));
    CHECK(m.unremoved_error_rad == 0.0);
    CHECK_FALSE(to_json(m, 0).contains("cycles_not_removed"));
}

}  // namespace test_scoring_cpp
