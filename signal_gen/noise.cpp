#include "noise.hpp"

#include <cmath>


namespace fringe {

Xoshiro256pp::Xoshiro256pp(std::uint64_t seed) {
    std::uint64_t z = seed;
    for (auto& s : s_) {
        z += 0x9e3779b97f4a7c15ULL;
        s = mix64(z);
    }
}

namespace {
constexpr int kLayers = 128;
constexpr double kR = 3.442619855899;          // start of the tail
constexpr double kV = 9.91256303526217e-3;     // area of each layer

struct ZigguratTables {
    double x[kLayers + 1];
    double ratio[kLayers];
    ZigguratTables() {
        double f = std::exp(-0.5 * kR * kR);
        x[0] = kV / f;  // the base layer includes the tail: width V/f(R)
        x[1] = kR;
        x[kLayers] = 0.0;
        for (int i = 2; i < kLayers; ++i) {
            x[i] = std::sqrt(-2.0 * std::log(kV / x[i - 1] + f));
            f = std::exp(-0.5 * x[i] * x[i]);
        }
        for (int i = 0; i < kLayers; ++i) ratio[i] = x[i + 1] / x[i];
    }
};
const ZigguratTables& tables() {
    static const ZigguratTables t;
    return t;
}

// A 64-bit draw: layer from the low 7 bits, u in [-1, 1) from the top 53.
inline std::uint64_t draw_layer(std::uint64_t bits) { return bits & (kLayers - 1); }
inline double draw_u(std::uint64_t bits) {
    return static_cast<double>(static_cast<std::int64_t>(bits >> 11)) * 0x1p-52 - 1.0;
}

double normal_tail(Xoshiro256pp& rng, bool negative) {
    double x, y;
    do {
        x = std::log(rng.uniform()) / kR;
        y = std::log(rng.uniform());
    } while (-2.0 * y < x * x);
    return negative ? x - kR : kR - x;
}
}  // namespace

double standard_normal(Xoshiro256pp& rng) { return standard_normal_from(rng.next(), rng); }

double standard_normal_from(std::uint64_t bits, Xoshiro256pp& rng) {
    const ZigguratTables& t = tables();
    for (bool first = true;; first = false) {
        if (!first) bits = rng.next();
        const auto i = draw_layer(bits);
        const double u = draw_u(bits);
        if (std::fabs(u) < t.ratio[i]) return u * t.x[i];
        if (i == 0) return normal_tail(rng, u < 0);
        const double x = u * t.x[i];
        const double f0 = std::exp(-0.5 * (t.x[i] * t.x[i] - x * x));
        const double f1 = std::exp(-0.5 * (t.x[i + 1] * t.x[i + 1] - x * x));
        if (f1 + rng.uniform() * (f0 - f1) < 1.0) return x;
    }
}

NoiseField::NoiseField(std::uint64_t seed, std::uint64_t stream_id, int streams)
    : seed_(mix64(seed ^ mix64(stream_id + 0x51ed270b2a1e6f1dULL))), streams_(streams),
      buf_(kNoiseChunk * static_cast<std::size_t>(streams)) {}

void fill_normals(std::uint64_t key, std::size_t n, double* out, std::uint64_t* bits,
                  std::uint32_t* missed) {
    const ZigguratTables& t = tables();
    constexpr std::uint64_t kGamma = 0x9e3779b97f4a7c15ULL;
    for (std::size_t i = 0; i < n; ++i) bits[i] = mix64(key + (i + 1) * kGamma);  // vectorises
    const double* x = t.x;
    const double* ratio = t.ratio;
    std::size_t n_missed = 0;
    for (std::size_t i = 0; i < n; ++i) {  // the fast path, branch-free
        const std::uint64_t layer = draw_layer(bits[i]);
        const double u = draw_u(bits[i]);
        out[i] = u * x[layer];
        missed[n_missed] = static_cast<std::uint32_t>(i);  // kept only if this draw missed
        n_missed += std::fabs(u) < ratio[layer] ? 0 : 1;
    }
    for (std::size_t j = 0; j < n_missed; ++j) {  // ~1 % of draws: finish the ziggurat
        const std::size_t i = missed[j];
        Xoshiro256pp rng(mix64(key ^ mix64(i + 0x632be59bd9b4e019ULL)));
        out[i] = standard_normal_from(bits[i], rng);
    }
}

void NoiseField::load_chunk(std::uint64_t chunk) {
    bits_.resize(buf_.size());
    missed_.resize(buf_.size());
    fill_normals(mix64(seed_ + mix64(chunk)), buf_.size(), buf_.data(), bits_.data(), missed_.data());
    cached_ = chunk;
}

bool NoiseField::view(std::uint64_t first, std::size_t n, const double** out) {
    const std::uint64_t chunk = first / kNoiseChunk;
    const std::size_t off = first % kNoiseChunk;
    if (n == 0 || off + n > kNoiseChunk) return false;
    if (chunk != cached_) load_chunk(chunk);
    for (int s = 0; s < streams_; ++s) out[s] = buf_.data() + static_cast<std::size_t>(s) * kNoiseChunk + off;
    return true;
}

void NoiseField::fill(std::uint64_t first, std::size_t n, double* const* out) {
    std::size_t i = 0;
    while (i < n) {
        const std::uint64_t k = first + i;
        const std::uint64_t chunk = k / kNoiseChunk;
        if (chunk != cached_) load_chunk(chunk);
        const std::size_t off = k % kNoiseChunk;
        const std::size_t take = std::min(n - i, kNoiseChunk - off);
        for (int s = 0; s < streams_; ++s) {
            const double* src = buf_.data() + static_cast<std::size_t>(s) * kNoiseChunk + off;
            double* dst = out[s] + i;
            for (std::size_t j = 0; j < take; ++j) dst[j] = src[j];
        }
        i += take;
    }
}

}  // namespace fringe
