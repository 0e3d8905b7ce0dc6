// Spectrum of a lane's scored error at the full sample rate (issue 11): Welch's method, streamed
// (Hann window, 50 % overlap, mean removed per segment), so a run of any length needs one segment
// of memory and no harmonic is aliased by decimation.
#pragma once

#include <nlohmann/json.hpp>

#include <complex>
#include <cstdint>
#include <vector>

namespace fringe {

// |X_k|^2 (k = 0..n/2) of the unscaled DFT of n real samples, n a power of two >= 4: the
// half-length complex FFT of the even and odd samples taken as one complex sequence, then split
// into the real input's bins. The complex FFT is Stockham's radix 4 (a radix-2 stage last when
// n/2 is not a power of 4) on split real and imaginary parts: natural order in and out (no bit
// reversal), each stage's butterflies a loop that vectorises; twiddles computed once, directly.
class RealPowerSpectrum {
public:
    explicit RealPowerSpectrum(std::size_t n);
    std::size_t size() const { return n_; }
    // power[k] += |X_k|^2 for k = 0..n/2 of x[0..n)
    void accumulate(const double* x, double* power);

private:
    std::size_t n_, m_;                    // m_ = n_ / 2 complex points
    std::vector<std::vector<double>> tw_;  // per radix-4 stage of length len: w^p, w^2p, w^3p (re, im), w = exp(-2 pi i / len)
    std::vector<double> split_re_, split_im_;  // exp(-2 pi i k / n_), k <= m_
    std::vector<double> buf_;              // the sequence and a stage's output, re and im (scratch)
};

class ErrorSpectrum {
public:
    static constexpr std::size_t kMaxSegment = 65536;
    static constexpr std::size_t kMinSegment = 16;
    static constexpr std::size_t kMaxBins = 2000;  // frequency axis in the JSON
    // segment_samples: a power of two >= kMinSegment (rounded down to one otherwise).
    ErrorSpectrum(double sample_rate_hz, std::size_t segment_samples);
    // Resolution first: a power of two giving >= 8 bins between harmonics of electrical_hz (Hann's
    // main lobe is 4 bins wide, so up to the 16x and beyond stay apart) and at least 4096 (so the
    // low frequencies where a tracker's error lives are resolved too), but no longer than a
    // quarter of the run (>= 7 averaged segments), within [kMinSegment, kMaxSegment].
    static std::size_t choose_segment(double sample_rate_hz, double electrical_hz, std::uint64_t scored_samples);
    // Scored error samples (rad) in order; ok[i]==0 (invalid) ends the current segment (gaps are not bridged).
    // ok may be null (all valid); a non-finite e_rad also ends the segment.
    void add(std::size_t n, const double* e_rad, const std::uint8_t* ok);
    std::size_t segments() const { return segments_; }
    std::size_t segment_samples() const { return n_; }
    // f_hz, order (f / electrical_hz; null when electrical_hz is 0), asd_rad_per_sqrt_hz, amplitude_rad (peak
    // amplitude of a sinusoid in that bin: at local maxima corrected for Hann scalloping by the two-bin ratio,
    // see spectrum.cpp), segments, segment_samples, resolution_hz. DC is left out (the mean is removed).
    // At most kMaxBins frequencies: groups of adjacent bins keep the bin of largest amplitude (peaks survive).
    nlohmann::json to_json(double electrical_hz) const;

private:
    void segment();
    double fs_;
    std::size_t n_;
    std::size_t segments_ = 0;
    std::vector<double> window_, buf_;  // buf_: the current run of contiguous valid samples, a ring of n_
    std::size_t start_ = 0, fill_ = 0;  // its oldest sample, and how many (< n_ between segments)
    std::vector<double> power_;         // sum over segments of |X_k|^2, k = 0..n_/2
    std::vector<double> x_;             // windowed segment (scratch)
    RealPowerSpectrum fft_;
    double s1_ = 0, s2_ = 0;            // sum of window, sum of window^2
};

}  // namespace fringe
