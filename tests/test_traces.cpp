// Plot traces and the error spectrum against analytic truth (issue 11: plots that do not alias).
#include "server/analysis/spectrum.hpp"
#include "server/analysis/traces.hpp"
#include "signal_gen/base/constants.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <random>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_traces_cpp {

using namespace fringe;
using nlohmann::json;

namespace {

// Feeds a recorder a constant-speed run: theta = 2 pi fe t, ideal quadrature of amplitude amp_v,
// one lane whose error is err(theta, t) (unwrapped, any multiple of 2 pi).
template <class Err>
void feed(TraceRecorder& r, std::uint64_t total, double fs, double fe, double amp_v, Err err, std::size_t block = 65536, double theta0_rad = 0) {
    std::vector<double> t(block), s(block), c(block), th(block), e(block);
    for (std::uint64_t k = 0; k < total; k += block) {
        const std::size_t m = static_cast<std::size_t>(std::min<std::uint64_t>(block, total - k));
        for (std::size_t i = 0; i < m; ++i) {
            t[i] = static_cast<double>(k + i) / fs;
            th[i] = theta0_rad + 2 * kPi * fe * t[i];
            s[i] = amp_v * std::sin(th[i]);
            c[i] = amp_v * std::cos(th[i]);
            e[i] = err(th[i], t[i]);
        }
        r.add(m, t.data(), s.data(), c.data(), th.data(), nullptr, {e.data()});
    }
}
}  // namespace

TEST_CASE("traces: the envelope keeps a fast error whose stride samples alias", "[traces]") {
    // 10^6 samples into 2000 buckets of 500: 8 fe = 200.1 Hz is 0.1 Hz from the stride rate
    // (200 Hz), so every 500th sample shows a slow 0.1 Hz beat instead of a 3e-3 rad ripple.
    const double fs = 100000, fe = 200.1 / 8, a = 3e-3;
    const std::uint64_t total = 1000000;
    TraceRecorder r(total, 2000, {"lane"});
    auto err = [&](double th, double) { return a * std::sin(8 * th) + 2 * kPi * 3; };  // unwrapped: +3 cycles
    feed(r, total, fs, fe, 0.5, err);
    const json j = r.to_json();
    REQUIRE(j["kind"] == "envelope");
    REQUIRE(j["bucket_samples"] == 500);
    const auto& mx = j["error_rad"]["lane"]["max"];
    const auto& mn = j["error_rad"]["lane"]["min"];
    REQUIRE(mx.size() == 2000);
    REQUIRE(j["t_s"].size() == 2000);
    CHECK(j["t_s"][1].get<double>() == Approx(500 / fs));
    double worst = 0;
    for (std::size_t b = 0; b < mx.size(); ++b) {
        worst = std::max({worst, std::fabs(mx[b].get<double>() - a) / a, std::fabs(mn[b].get<double>() + a) / a});
    }
    CHECK(worst < 0.01);
    // What stride sampling shows: the same signal at every 500th sample stays far below the ripple
    // in most of the run (the failure this replaces).
    std::size_t small = 0;
    for (std::uint64_t k = 0; k < total; k += 500)
        if (std::fabs(std::remainder(err(2 * kPi * fe * static_cast<double>(k) / fs, 0), 2 * kPi)) < 0.5 * a) ++small;
    CHECK(small > 500);
    // sin/cos envelopes hold the full swing in every bucket (each bucket spans 1/8 cycle... at least
    // the true sample range): max >= min everywhere, overall range +-0.5 V.
    double smax = -1, smin = 1;
    for (std::size_t b = 0; b < 2000; ++b) {
        CHECK(j["sin_v"]["max"][b].get<double>() >= j["sin_v"]["min"][b].get<double>());
        smax = std::max(smax, j["sin_v"]["max"][b].get<double>());
        smin = std::min(smin, j["sin_v"]["min"][b].get<double>());
    }
    CHECK(smax == Approx(0.5).margin(1e-4));
    CHECK(smin == Approx(-0.5).margin(1e-4));
}

TEST_CASE("traces: the folded Lissajous cycle is a closed curve of short segments, points are real samples", "[traces]") {
    const double fs = 100000, fe = 106.72358591248666, A = 0.8;
    const std::uint64_t total = 100000;
    const std::size_t K = TraceRecorder::kAngleBins;
    TraceRecorder r(total, 2000, {"lane"});
    feed(r, total, fs, fe, A, [](double, double) { return 0.0; }, 4096);
    const json j = r.to_json();
    const auto& cyc = j["lissajous"]["cycle"];
    REQUIRE(cyc["sin_v"].size() == K);
    double longest = 0;
    for (std::size_t k = 0; k < K; ++k) {
        const std::size_t n = (k + 1) % K;  // closed: the last bin joins the first
        REQUIRE(cyc["sin_v"][k].is_number());
        longest = std::max(longest, std::hypot(cyc["sin_v"][n].get<double>() - cyc["sin_v"][k].get<double>(),
                                               cyc["cos_v"][n].get<double>() - cyc["cos_v"][k].get<double>()));
    }
    CHECK(longest < 2 * kPi * A / static_cast<double>(K) * 1.5);
    // Stride samples joined in order (the old plot): segments of ~1/19 of the circle.
    const double stride_step = 2 * A * std::sin(kPi * fe * 50 / fs);
    CHECK(stride_step > 5 * longest);
    // Points: one real sample per bucket, on the circle, spread over the whole cycle.
    const auto& ps = j["lissajous"]["points"]["sin_v"];
    const auto& pc = j["lissajous"]["points"]["cos_v"];
    REQUIRE(ps.size() == 2000);
    std::vector<int> octant(8, 0);
    for (std::size_t i = 0; i < ps.size(); ++i) {
        CHECK(std::hypot(ps[i].get<double>(), pc[i].get<double>()) == Approx(A).epsilon(1e-5));
        double ang = std::atan2(ps[i].get<double>(), pc[i].get<double>());
        if (ang < 0) ang += 2 * kPi;
        ++octant[static_cast<int>(ang / (2 * kPi) * 8) % 8];
    }
    for (int o : octant) CHECK(o > 100);
}

TEST_CASE("traces: Lissajous points do not all fall on one phase when the bucket is a whole number of periods", "[traces]") {
    // 500-sample buckets, electrical period 250 samples: a sample at a fixed offset is always the same phase.
    const double fs = 100000, fe = fs / 250;
    TraceRecorder r(1000000, 2000, {"lane"});
    feed(r, 1000000, fs, fe, 1.0, [](double, double) { return 0.0; });
    const json j = r.to_json();
    std::vector<int> octant(8, 0);
    for (std::size_t i = 0; i < j["lissajous"]["points"]["sin_v"].size(); ++i) {
        double ang = std::atan2(j["lissajous"]["points"]["sin_v"][i].get<double>(), j["lissajous"]["points"]["cos_v"][i].get<double>());
        if (ang < 0) ang += 2 * kPi;
        ++octant[static_cast<int>(ang / (2 * kPi) * 8) % 8];
    }
    for (int o : octant) CHECK(o > 100);
}

TEST_CASE("traces: by_angle recovers a known 1x error, samples before fold_from_s are not folded", "[traces]") {
    const double fs = 100000, fe = 106.72358591248666, a = 1e-3, phase = 0.3;
    const std::uint64_t total = 200000;
    const std::size_t K = TraceRecorder::kAngleBins;
    TraceRecorder r(total, 2000, {"ekf"}, 0.1);
    // Before 0.1 s a large transient, which must not reach the fold.
    // theta0 puts no sample on a bin edge (at 937 samples per period every 937th would sit on 0).
    const double theta0 = 1e-3;
    feed(r, total, fs, fe, 1.0, [&](double th, double t) { return t < 0.1 ? 1.0 : a * std::cos(th - phase); }, 65536, theta0);
    const json j = r.to_json();
    const auto& f = j["by_angle"]["error_rad"]["ekf"];
    const double dth = 2 * kPi / static_cast<double>(K);
    // The exact bin means: fe is 937 samples per period, so each bin holds the same 3 or 4 phases
    // every cycle; average the true error over exactly those samples.
    std::vector<double> sum(K, 0.0);
    std::vector<double> cnt(K, 0.0);
    for (std::uint64_t i = 10000; i < total; ++i) {
        const double th = theta0 + 2 * kPi * fe * (static_cast<double>(i) / fs);
        double w = std::fmod(th, 2 * kPi);
        if (w < 0) w += 2 * kPi;
        const auto k = std::min<std::size_t>(static_cast<std::size_t>(w * (static_cast<double>(K) / (2 * kPi))), K - 1);
        sum[k] += a * std::cos(th - phase);
        cnt[k] += 1;
    }
    std::uint64_t counted = 0;
    for (std::size_t k = 0; k < K; ++k) {
        const double th = j["by_angle"]["theta_rad"][k].get<double>();
        CHECK(th == Approx((static_cast<double>(k) + 0.5) * dth));
        CHECK(f["mean"][k].get<double>() == Approx(sum[k] / cnt[k]).epsilon(1e-5));  // the JSON keeps 6 digits
        // and it is the 1x curve at the bin centre, to within the bin's width
        CHECK(f["mean"][k].get<double>() == Approx(a * std::cos(th - phase)).margin(a * dth / 2));
        CHECK(f["min"][k].get<double>() <= f["mean"][k].get<double>());
        CHECK(f["max"][k].get<double>() >= f["mean"][k].get<double>());
        CHECK(f["max"][k].get<double>() < 1.01 * a);
        counted += f["count"][k].get<std::uint64_t>();
    }
    CHECK(counted == total - 10000);
    // The time envelope does show the transient.
    CHECK(j["error_rad"]["ekf"]["max"][0].get<double>() == Approx(1.0));
}

TEST_CASE("traces: NaN samples are skipped, a bucket with no valid value is null", "[traces]") {
    const double fs = 1000;
    TraceRecorder r(1000, 10, {"a", "b"});
    std::vector<double> t(1000), s(1000), c(1000), th(1000), ea(1000), eb(1000);
    std::vector<std::uint8_t> known(1000, 1);
    const double nan = std::numeric_limits<double>::quiet_NaN();
    for (std::size_t i = 0; i < 1000; ++i) {
        t[i] = static_cast<double>(i) / fs;
        th[i] = 0.01 * static_cast<double>(i);
        s[i] = std::sin(th[i]);
        c[i] = std::cos(th[i]);
        ea[i] = i < 100 ? nan : 0.001;            // lane a: nothing valid in bucket 0
        eb[i] = i % 2 ? nan : -0.002;             // lane b: every other sample
        if (i >= 900) { s[i] = nan; known[i] = 0; }  // last bucket: no sin, no truth
    }
    r.add(1000, t.data(), s.data(), c.data(), th.data(), known.data(), {ea.data(), eb.data()});
    const json j = r.to_json();
    CHECK(j["error_rad"]["a"]["max"][0].is_null());
    CHECK(j["error_rad"]["a"]["min"][0].is_null());
    CHECK(j["error_rad"]["a"]["max"][1].get<double>() == Approx(0.001));
    CHECK(j["error_rad"]["b"]["min"][3].get<double>() == Approx(-0.002));
    CHECK(j["sin_v"]["max"][9].is_null());
    CHECK(j["cos_v"]["max"][9].is_number());
    std::uint64_t na = 0, nb = 0;
    for (std::size_t k = 0; k < j["by_angle"]["error_rad"]["a"]["count"].size(); ++k) {
        na += j["by_angle"]["error_rad"]["a"]["count"][k].get<std::uint64_t>();
        nb += j["by_angle"]["error_rad"]["b"]["count"][k].get<std::uint64_t>();
    }
    CHECK(na == 800);  // valid and truth known: samples 100..899
    CHECK(nb == 450);
    CHECK(j["lissajous"]["points"]["sin_v"].size() <= 9);  // no point from the bucket without sin
    const std::string dumped = j.dump();
    CHECK(dumped.find("NaN") == std::string::npos);
    CHECK(dumped.find("nan") == std::string::npos);
}

TEST_CASE("traces: an aborted run keeps only the buckets it reached", "[traces]") {
    TraceRecorder r(1000000, 100, {"a"});
    feed(r, 25000, 1e5, 100, 1.0, [](double, double) { return 0.0; });
    CHECK(r.to_json()["t_s"].size() == 3);
}

namespace {
json size_run(std::uint64_t total) {
    TraceRecorder r(total, 2000, {"lane"});
    feed(r, total, 1e6, 1234.5, 1.0, [](double th, double) { return 1e-3 * std::sin(3 * th); });
    return r.to_json();
}
}  // namespace

TEST_CASE("traces: size is independent of the run length", "[traces]") {
    const json a = size_run(100000), b = size_run(10000000);
    CHECK(a["t_s"].size() == b["t_s"].size());
    CHECK(a["lissajous"]["points"]["sin_v"].size() == b["lissajous"]["points"]["sin_v"].size());
    // 100x the samples, no bigger (numbers keep 6 significant digits, so the text may shrink)
    CHECK(b.dump().size() <= a.dump().size() * 11 / 10);
    CHECK(b.dump().size() < 300000);  // one lane, 2000 buckets, 256 angle bins
}

TEST_CASE("traces: 10^8 samples, same JSON size as 10^5", "[traces][.long][long]") {
    const json a = size_run(100000), b = size_run(100000000);
    CHECK(b["samples"] == 100000000);
    CHECK(a["t_s"].size() == b["t_s"].size());
    CHECK(b.dump().size() <= a.dump().size() * 11 / 10);
}

// ---- spectrum --------------------------------------------------------------------------

namespace {
// Largest amplitude and its frequency within [f_lo, f_hi] of a spectrum JSON.
std::pair<double, double> peak_in(const json& s, double f_lo, double f_hi, const char* axis = "f_hz") {
    double best = -1, at = 0;
    for (std::size_t i = 0; i < s[axis].size(); ++i) {
        const double f = s[axis][i].get<double>();
        if (f < f_lo || f > f_hi) continue;
        if (s["amplitude_rad"][i].get<double>() > best) { best = s["amplitude_rad"][i].get<double>(); at = f; }
    }
    return {best, at};
}
}  // namespace

TEST_CASE("spectrum: a tone's amplitude within 5 % and frequency within a bin, anywhere between bins", "[spectrum]") {
    const double fs = 100000, a = 3e-3;
    const std::size_t N = 8192;
    const double res = fs / N;
    for (double frac : {0.0, 0.13, 0.5, 0.77}) {
        const double f0 = (101 + frac) * res;
        ErrorSpectrum sp(fs, N);
        std::vector<double> e(300000);
        for (std::size_t i = 0; i < e.size(); ++i) e[i] = 0.01 + a * std::sin(2 * kPi * f0 * static_cast<double>(i) / fs + 0.4);
        sp.add(e.size(), e.data(), nullptr);
        CHECK(sp.segments() == (300000 - N) / (N / 2) + 1);
        const json s = sp.to_json(0);
        CHECK(s["order"][0].is_null());
        CHECK(s["resolution_hz"].get<double>() == Approx(res));
        const auto [amp, f] = peak_in(s, 0, fs / 2);
        INFO("tone at bin 101 + " << frac << ": " << amp << " rad at " << f << " Hz");
        CHECK(amp == Approx(a).epsilon(0.05));
        CHECK(std::fabs(f - f0) <= res);
    }
}

TEST_CASE("spectrum: white noise gives a flat ASD of sigma*sqrt(2/fs)", "[spectrum]") {
    const double fs = 50000, sigma = 1e-3;
    ErrorSpectrum sp(fs, 2048);
    std::mt19937_64 rng(7);
    std::normal_distribution<double> g(0, sigma);
    std::vector<double> e(1000000);
    for (auto& v : e) v = g(rng);
    sp.add(e.size(), e.data(), nullptr);
    const json s = sp.to_json(0);
    REQUIRE(s["decimation"] == 1);
    double sum = 0;
    std::size_t n = 0;
    for (std::size_t i = 1; i + 1 < s["f_hz"].size(); ++i, ++n) sum += s["asd_rad_per_sqrt_hz"][i].get<double>();  // skip DC-adjacent bin and Nyquist
    CHECK(sum / static_cast<double>(n) == Approx(sigma * std::sqrt(2 / fs)).epsilon(0.05));
}

TEST_CASE("spectrum: gaps end segments (never bridged)", "[spectrum]") {
    const std::size_t N = 1024;
    ErrorSpectrum sp(1000, N);
    std::vector<double> e(N * 20, 1e-3);
    std::vector<std::uint8_t> ok(e.size(), 1);
    for (std::size_t i = N - 1; i < ok.size(); i += N) ok[i] = 0;  // runs of N-1 valid samples
    sp.add(e.size(), e.data(), ok.data());
    CHECK(sp.segments() == 0);
    const json s0 = sp.to_json(10);
    CHECK(s0["segments"] == 0);
    CHECK(s0["f_hz"].empty());
    // The same samples without gaps make segments; a NaN ends a segment like ok = 0.
    ErrorSpectrum all(1000, N);
    all.add(e.size(), e.data(), nullptr);
    CHECK(all.segments() == 39);
    ErrorSpectrum nan(1000, N);
    std::vector<double> en(N + N / 2, 1e-3);
    en[N / 2] = std::numeric_limits<double>::quiet_NaN();
    nan.add(en.size(), en.data(), nullptr);
    CHECK(nan.segments() == 0);
    // Chunking does not matter: one sample at a time gives the same segments.
    ErrorSpectrum one(1000, N);
    for (std::size_t i = 0; i < N * 3; ++i) one.add(1, &e[i], nullptr);
    CHECK(one.segments() == 5);
}

TEST_CASE("spectrum: tones at 8x and 12x appear at orders 8 and 12", "[spectrum]") {
    const double fs = 100000, fe = 106.72358591248666;
    const std::uint64_t n = 500000;
    const std::size_t N = ErrorSpectrum::choose_segment(fs, fe, n);
    CHECK(N == 8192);
    ErrorSpectrum sp(fs, N);
    std::vector<double> e(n);
    for (std::size_t i = 0; i < n; ++i) {
        const double th = 2 * kPi * fe * static_cast<double>(i) / fs;
        e[i] = 2e-4 * std::cos(8 * th + 1) + 5e-5 * std::sin(12 * th);
    }
    sp.add(n, e.data(), nullptr);
    const json s = sp.to_json(fe);
    const double res_order = s["resolution_hz"].get<double>() / fe;
    const auto [a8, o8] = peak_in(s, 7.5, 8.5, "order");
    const auto [a12, o12] = peak_in(s, 11.5, 12.5, "order");
    CHECK(std::fabs(o8 - 8) <= res_order);
    CHECK(std::fabs(o12 - 12) <= res_order);
    CHECK(a8 == Approx(2e-4).epsilon(0.05));
    CHECK(a12 == Approx(5e-5).epsilon(0.05));
    CHECK(peak_in(s, 9.5, 10.5, "order").first < 1e-3 * 2e-4);  // nothing between them
}

TEST_CASE("spectrum: segment choice", "[spectrum]") {
    // fig10c: >= 8 bins per harmonic spacing (7496 samples -> 8192), room for 7+ segments
    CHECK(ErrorSpectrum::choose_segment(1e5, 106.7, 90000) == 8192);
    // a short run trades resolution for averaging
    CHECK(ErrorSpectrum::choose_segment(1e5, 106.7, 10000) == 2048);
    // slow motion: capped
    CHECK(ErrorSpectrum::choose_segment(1e6, 1.0, 100000000) == ErrorSpectrum::kMaxSegment);
    CHECK(ErrorSpectrum::choose_segment(1e5, 0, 1000000) == 4096);
    CHECK(ErrorSpectrum::choose_segment(1e5, 0, 10) == ErrorSpectrum::kMinSegment);
}

TEST_CASE("spectrum: the frequency axis is bounded and keeps peaks", "[spectrum]") {
    const double fs = 1e6;
    const std::size_t N = 65536;  // 32768 bins -> groups of 17
    ErrorSpectrum sp(fs, N);
    std::vector<double> e(N * 2);
    const double f0 = 12345.6;
    for (std::size_t i = 0; i < e.size(); ++i) e[i] = 1e-3 * std::sin(2 * kPi * f0 * static_cast<double>(i) / fs);
    sp.add(e.size(), e.data(), nullptr);
    const json s = sp.to_json(f0 / 4);
    CHECK(s["f_hz"].size() <= ErrorSpectrum::kMaxBins);
    const auto [a, f] = peak_in(s, 0, fs);
    CHECK(a == Approx(1e-3).epsilon(0.05));
    CHECK(std::fabs(f - f0) <= fs / N);
    CHECK(peak_in(s, 3.9, 4.1, "order").first == Approx(a));
}

TEST_CASE("spectrum: the real-input FFT's power equals a direct DFT's", "[spectrum]") {
    std::mt19937_64 rng(7);
    std::normal_distribution<double> g(0.0, 1.0);
    // powers of 4 and not (a radix-2 stage last), up to the segment lengths runs use
    for (std::size_t n : {4u, 8u, 16u, 32u, 64u, 128u, 1024u, 8192u}) {
        std::vector<double> x(n);
        for (auto& v : x) v = g(rng);
        x[n / 3] += 40.0;  // a spike: every bin carries power
        RealPowerSpectrum fft(n);
        std::vector<double> got(n / 2 + 1, 0.0);
        fft.accumulate(x.data(), got.data());
        fft.accumulate(x.data(), got.data());  // it accumulates: twice the power
        double top = 0;
        std::vector<double> want(n / 2 + 1);
        for (std::size_t k = 0; k <= n / 2; ++k) {
            long double re = 0, im = 0;
            for (std::size_t i = 0; i < n; ++i) {
                const long double a_rad = -2.0L * 3.14159265358979323846264338327950288L * static_cast<long double>((k * i) % n) / static_cast<long double>(n);
                re += x[i] * std::cos(a_rad);
                im += x[i] * std::sin(a_rad);
            }
            want[k] = static_cast<double>(2 * (re * re + im * im));
            top = std::max(top, want[k]);
        }
        for (std::size_t k = 0; k <= n / 2; ++k) {
            INFO("n = " << n << ", bin " << k);
            CHECK(std::fabs(got[k] - want[k]) <= 1e-12 * top);
        }
    }
    CHECK_THROWS(RealPowerSpectrum(12));
    CHECK_THROWS(RealPowerSpectrum(2));
}

}  // namespace test_traces_cpp
