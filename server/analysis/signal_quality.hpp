// Signal quality of a sin/cos pair as encoder testers grade it (docs/signal-quality.md), from
// the signals alone: no truth is needed. Each electrical period is cut out of the stream
// between two crossings of the raw angle psi = atan2(A, B) through a multiple of 2 pi; inside
// it the electrical angle is taken as linear in time (the motion is smooth within a period), and
// each channel is fitted with a Fourier series up to the 8th harmonic by trapezoidal
// integration. Per period: amplitude (fundamental, V peak and Vpp), offset, A/B ratio, phase
// between A and B, on/off ratio TV (from the time the channel is above 0 V), asymmetry SYM,
// harmonics h2..h8 and THD, noise about the fitted shape, radius sqrt(A^2 + B^2) min/max and
// the signal frequency. The run's figures are the means over its periods with the worst
// period beside them; per-period figures are kept in at most kMaxRecords buckets (flat memory).
// A channel named A is the sin channel, B the cos channel (docs/model.md).
#pragma once

#include <nlohmann/json.hpp>

#include <array>
#include <limits>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace fringe {

struct ChannelQuality {
    double amplitude_v = 0;      // fundamental, V peak
    double vpp_v = 0;            // 2 x amplitude_v
    double offset_v = 0;         // mean over the period (the 0th Fourier term)
    double phase_rad = 0;        // fundamental as amplitude sin(phi + phase)
    double tv_deg = 0;           // on/off ratio: high time - 180 deg (high = above 0 V)
    double sym = 0;              // |P - N| / (2 M), P = max, N = -min, M = max - min of the fitted shape
    std::array<double, 7> h_percent{};  // h2..h8, % of the fundamental
    double thd_percent = 0;      // sqrt(sum h2..h8^2), % of the fundamental
    double noise_v_rms = 0;      // rms of the samples about the fitted shape
    double max_v = 0, min_v = 0; // of the fitted shape
};

struct PeriodQuality {
    double t_start_s = 0, t_end_s = 0;
    int direction = 1;           // +1: psi increasing, -1: decreasing
    std::size_t samples = 0;
    ChannelQuality a, b;
    double ab_ratio = 0;         // amplitude A / amplitude B
    double phase_deg = 0;        // phase of B minus phase of A (90 ideal), in (-180, 180]
    double radius_min_v = 0, radius_max_v = 0;  // sqrt(A^2 + B^2) over the samples
    double freq_hz = 0;          // 1 / period
};

class SignalQuality {
public:
    static constexpr std::size_t kMaxRecords = 2048;     // per-period buckets kept
    static constexpr std::size_t kLissajousBins = 128;   // electrical-angle bins of the Lissajous figure
    static constexpr std::size_t kMaxPeriodSamples = 1u << 17;  // a longer period is skipped (counted)
    static constexpr int kHarmonics = 8;
    static constexpr std::size_t kMinPeriodSamples = 24;  // 17 coefficients and some noise left
    static constexpr double kMaxPeriodChange = 0.05;      // a period 5 % longer or shorter than the one before is not at a steady speed
    static constexpr double kMaxAbsV = 1e100;
    static constexpr std::size_t kLeastSquaresBelow = 128;  // fewer points a period: least squares, else the trapezoid rule             // beyond: a gap (the squares would overflow)

    void add(const double* t_s, const double* a_v, const double* b_v, std::size_t n);
    // The figures of one period from its points: phi_rad[i] the electrical angle (0..2 pi
    // forwards, 0..-2 pi backwards), first and last points on the period's ends.
    static PeriodQuality analyse_period(const std::vector<double>& t_s, const std::vector<double>& phi_rad, const std::vector<double>& a_v,
                                        const std::vector<double>& b_v);
    // {"periods", "skipped_periods", "a", "b", "ab_ratio", "phase_deg", ...} (docs/signal-quality.md);
    // {"periods": 0, "note": why} when no whole period was seen.
    nlohmann::json to_json() const;

    std::size_t periods() const { return periods_; }
    const PeriodQuality& mean() const { return mean_; }

private:
    void close_period(double t_end_s, double a_end_v, double b_end_v);
    void record(const PeriodQuality& p, long long position);
    void start_period(double t_s, double a_v, double b_v, long long k, int direction);

    // The stream
    bool have_prev_ = false;
    double prev_t_ = 0, prev_a_ = 0, prev_b_ = 0;
    int prev_q_ = 0;          // quadrant of the last sample
    long long quarter_ = 0;   // quadrants passed, unwrapped: psi is in [quarter pi/2, (quarter + 1) pi/2)
    static long long floor_div4(long long q) { return q >= 0 ? q / 4 : -((-q + 3) / 4); }
    // The open period
    bool open_ = false;
    long long k_start_ = 0;  // starts at psi = 2 pi k_start_
    int dir_ = 1;
    bool too_long_ = false;
    std::vector<double> pt_, pa_, pb_;
    std::vector<double> phi_;          // the closing period's angles (scratch)
    std::vector<std::uint32_t> bins_;  // its samples' Lissajous bins (scratch)
    // Totals
    std::size_t periods_ = 0, skipped_ = 0, samples_ = 0;
    std::size_t skipped_short_ = 0, skipped_long_ = 0;  // fewer than kMinPeriodSamples; more than kMaxPeriodSamples
    std::size_t skipped_unsteady_ = 0;                 // speed changed, first after a gap or a turn
    std::size_t out_of_range_ = 0;                     // samples beyond kMaxAbsV
    double prev_period_end_ = std::numeric_limits<double>::quiet_NaN(), prev_period_T_ = 0;
    int prev_period_dir_ = 0;
    PeriodQuality sum_{}, mean_{}, worst_lo_{}, worst_hi_{};
    bool have_worst_ = false;
    double radius_min_v_ = 0, radius_max_v_ = 0;
    // Recording: buckets of whole periods, each the mean of the periods in it.
    struct Record {
        std::size_t first = 0, count = 0;
        long long position = 0;  // the first period's place: it spans electrical angles [2 pi position, 2 pi (position + 1)) from the start's
        double t_s = 0, vpp_a = 0, vpp_b = 0, ratio = 0, phase_deg = 0, tv_a = 0, tv_b = 0, offset_a = 0, offset_b = 0;
    };
    std::vector<Record> records_;
    std::size_t per_record_ = 1;  // periods per bucket (doubles when full)
    Record pending_{};
    // The Lissajous figure of the analysed periods: each sample binned by its electrical angle
    // within its period (bin k covers [k, k + 1) 2 pi / kLissajousBins from A rising through 0
    // with B > 0), the bin's mean A and B and the least and greatest radius sqrt(A^2 + B^2).
    void bin_lissajous(const std::vector<double>& phi_rad);
    struct LissajousBin {
        double sum_a_v = 0, sum_b_v = 0, r2_min = std::numeric_limits<double>::infinity(), r2_max = 0;
        std::size_t count = 0;
    };
    std::vector<LissajousBin> lissajous_ = std::vector<LissajousBin>(kLissajousBins);
};

}  // namespace fringe
