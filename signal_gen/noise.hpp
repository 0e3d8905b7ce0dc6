// Deterministic noise. The noise of sample k is a function of (seed, stream, k) only, so
// blocks of any size give the same output as one big block: samples are grouped in
// chunks of kNoiseChunk, and normal i of a chunk is a function of a hash of (seed, stream,
// chunk index) and i: counter-based bits (splitmix64) through a ziggurat (see fill_normals).
#pragma once

#include <array>
#include <cstdint>
#include <vector>

namespace fringe {

// splitmix64 finaliser: a bijective 64-bit mixer.
constexpr std::uint64_t mix64(std::uint64_t z) {
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

class Xoshiro256pp {
public:
    explicit Xoshiro256pp(std::uint64_t seed);
    std::uint64_t next() {
        const std::uint64_t result = rotl(s_[0] + s_[3], 23) + s_[0];
        const std::uint64_t t = s_[1] << 17;
        s_[2] ^= s_[0];
        s_[3] ^= s_[1];
        s_[1] ^= s_[2];
        s_[0] ^= s_[3];
        s_[2] ^= t;
        s_[3] = rotl(s_[3], 45);
        return result;
    }
    // Uniform in (0, 1].
    double uniform() { return (static_cast<double>(next() >> 11) + 1.0) * 0x1p-53; }

private:
    static std::uint64_t rotl(std::uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
    std::array<std::uint64_t, 4> s_{};
};

// Standard normal by the 128-layer ziggurat (Marsaglia & Tsang; Doornik's ZIGNOR layout):
// one 64-bit draw on the fast path (~97 % of calls: the mean of x[i+1]/x[i]).
double standard_normal(Xoshiro256pp& rng);

// n standard normals that depend only on (key, i): counter-based bits (splitmix64 of
// key + i), the ziggurat's fast path over the whole array (branch-free, sixteen at a time
// with AVX-512; it notes where a draw missed), then only the ~2.8 % of missed draws
// finished with further counter-based bits keyed by (key, i). `missed` needs n entries. The
// numbers are the same with and without AVX-512; `portable` forces the scalar path (for
// tests that check so).
void fill_normals(std::uint64_t key, std::size_t n, double* out, std::uint32_t* missed,
                  bool portable = false);

constexpr std::size_t kNoiseChunk = 4096;

// `streams` independent standard normals per sample.
class NoiseField {
public:
    NoiseField(std::uint64_t seed, std::uint64_t stream_id, int streams);
    // out[s][i] = normal number s of sample first + i, for i < n.
    void fill(std::uint64_t first, std::size_t n, double* const* out);
    // The same numbers without a copy when samples first .. first + n - 1 lie in one chunk
    // (the generator's tiles always do when a block starts at a multiple of 1024): out[s]
    // points into this field's buffer, valid until the next fill or view. False otherwise.
    bool view(std::uint64_t first, std::size_t n, const double** out);

private:
    void load_chunk(std::uint64_t chunk);
    std::uint64_t seed_;
    int streams_;
    std::uint64_t cached_ = ~0ULL;
    std::vector<double> buf_;  // kNoiseChunk * streams_, stream-major
    std::vector<std::uint32_t> missed_;
};

}  // namespace fringe
