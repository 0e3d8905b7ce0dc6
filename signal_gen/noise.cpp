#include "noise.hpp"

#include <cmath>

#if defined(__AVX512F__) && defined(__AVX512DQ__)
#include <immintrin.h>
#define FRINGE_ZIGGURAT_AVX512 1
#endif

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
    alignas(64) double x[kLayers + 1];
    alignas(64) double ratio[kLayers];
    double f[kLayers + 1];  // exp(-x^2/2): the density at each layer's edge
    ZigguratTables() {
        double fr = std::exp(-0.5 * kR * kR);
        x[0] = kV / fr;  // the base layer includes the tail: width V/f(R)
        x[1] = kR;
        x[kLayers] = 0.0;
        for (int i = 2; i < kLayers; ++i) {
            x[i] = std::sqrt(-2.0 * std::log(kV / x[i - 1] + fr));
            fr = std::exp(-0.5 * x[i] * x[i]);
        }
        for (int i = 0; i < kLayers; ++i) ratio[i] = x[i + 1] / x[i];
        for (int i = 0; i <= kLayers; ++i) f[i] = std::exp(-0.5 * x[i] * x[i]);
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
        // The wedge: x is accepted with the probability that a uniform height between the
        // density at the layer's outer edge x[i] and inner edge x[i+1] lies under the density.
        const double x = u * t.x[i];
        if (t.f[i] + rng.uniform() * (t.f[i + 1] - t.f[i]) < std::exp(-0.5 * x * x)) return x;
    }
}

NoiseField::NoiseField(std::uint64_t seed, std::uint64_t stream_id, int streams)
    : seed_(mix64(seed ^ mix64(stream_id + 0x51ed270b2a1e6f1dULL))), streams_(streams),
      buf_(kNoiseChunk * static_cast<std::size_t>(streams)) {}

namespace {
constexpr std::uint64_t kGamma = 0x9e3779b97f4a7c15ULL;  // splitmix64's Weyl increment

// The draw of normal i: splitmix64 of key + (i + 1) * gamma.
inline std::uint64_t draw_bits(std::uint64_t key, std::size_t i) { return mix64(key + (i + 1) * kGamma); }

// The fast path for draws [begin, n): out[i] = u * x[layer], and the indices of draws that
// missed it (|u| >= ratio[layer]) appended to missed. Returns the new count of missed draws.
std::size_t fast_pass_scalar(std::uint64_t key, std::size_t begin, std::size_t n, double* out,
                             std::uint32_t* missed, std::size_t n_missed) {
    const ZigguratTables& t = tables();
    for (std::size_t i = begin; i < n; ++i) {  // branch-free
        const std::uint64_t bits = draw_bits(key, i);
        const std::uint64_t layer = draw_layer(bits);
        const double u = draw_u(bits);
        out[i] = u * t.x[layer];
        missed[n_missed] = static_cast<std::uint32_t>(i);  // kept only if this draw missed
        n_missed += std::fabs(u) < t.ratio[layer] ? 0 : 1;
    }
    return n_missed;
}

#ifdef FRINGE_ZIGGURAT_AVX512
// The same fast path eight draws at a time, with the 128-entry tables held in registers:
// two-source permutes pick within each group of 16 entries and blends on bits 4-6 of the
// layer pick the group. Gathers would be simpler but are microcoded (slow) on recent Intel
// cores. Every lane computes exactly what fast_pass_scalar computes (the same IEEE
// operations, no contraction), so both paths give identical numbers.
inline __m512d lookup128(const __m512d* tab, __m512i idx, __mmask8 b4, __mmask8 b5, __mmask8 b6) {
    const __m512d g0 = _mm512_permutex2var_pd(tab[0], idx, tab[1]);
    const __m512d g1 = _mm512_permutex2var_pd(tab[2], idx, tab[3]);
    const __m512d g2 = _mm512_permutex2var_pd(tab[4], idx, tab[5]);
    const __m512d g3 = _mm512_permutex2var_pd(tab[6], idx, tab[7]);
    const __m512d g4 = _mm512_permutex2var_pd(tab[8], idx, tab[9]);
    const __m512d g5 = _mm512_permutex2var_pd(tab[10], idx, tab[11]);
    const __m512d g6 = _mm512_permutex2var_pd(tab[12], idx, tab[13]);
    const __m512d g7 = _mm512_permutex2var_pd(tab[14], idx, tab[15]);
    const __m512d h0 = _mm512_mask_blend_pd(b4, g0, g1), h1 = _mm512_mask_blend_pd(b4, g2, g3);
    const __m512d h2 = _mm512_mask_blend_pd(b4, g4, g5), h3 = _mm512_mask_blend_pd(b4, g6, g7);
    const __m512d k0 = _mm512_mask_blend_pd(b5, h0, h1), k1 = _mm512_mask_blend_pd(b5, h2, h3);
    return _mm512_mask_blend_pd(b6, k0, k1);
}

std::size_t fast_pass_avx512(std::uint64_t key, std::size_t n, double* out, std::uint32_t* missed) {
    const ZigguratTables& t = tables();
    __m512d xt[16], rt[16];
    for (int j = 0; j < 16; ++j) {
        xt[j] = _mm512_load_pd(t.x + 8 * j);
        rt[j] = _mm512_load_pd(t.ratio + 8 * j);
    }
    const __m512i c1 = _mm512_set1_epi64(static_cast<long long>(0xbf58476d1ce4e5b9ULL));
    const __m512i c2 = _mm512_set1_epi64(static_cast<long long>(0x94d049bb133111ebULL));
    const __m512i step = _mm512_set1_epi64(static_cast<long long>(8 * kGamma));
    const __m512i layer_mask = _mm512_set1_epi64(kLayers - 1);
    const __m512i bit4 = _mm512_set1_epi64(16), bit5 = _mm512_set1_epi64(32), bit6 = _mm512_set1_epi64(64);
    const __m512d scale = _mm512_set1_pd(0x1p-52), one = _mm512_set1_pd(1.0);
    // Lane l of z holds key + (i + l + 1) * gamma (wrapping arithmetic, as in draw_bits).
    __m512i z = _mm512_add_epi64(_mm512_set1_epi64(static_cast<long long>(key)),
                                 _mm512_mullo_epi64(_mm512_setr_epi64(1, 2, 3, 4, 5, 6, 7, 8),
                                                    _mm512_set1_epi64(static_cast<long long>(kGamma))));
    std::size_t n_missed = 0, i = 0;
    for (; i + 8 <= n; i += 8, z = _mm512_add_epi64(z, step)) {
        __m512i b = _mm512_xor_si512(z, _mm512_srli_epi64(z, 30));  // mix64
        b = _mm512_mullo_epi64(b, c1);
        b = _mm512_xor_si512(b, _mm512_srli_epi64(b, 27));
        b = _mm512_mullo_epi64(b, c2);
        b = _mm512_xor_si512(b, _mm512_srli_epi64(b, 31));
        const __m512i layer = _mm512_and_si512(b, layer_mask);
        const __m512d u = _mm512_sub_pd(_mm512_mul_pd(_mm512_cvtepi64_pd(_mm512_srli_epi64(b, 11)), scale), one);
        const __mmask8 m4 = _mm512_test_epi64_mask(layer, bit4);
        const __mmask8 m5 = _mm512_test_epi64_mask(layer, bit5);
        const __mmask8 m6 = _mm512_test_epi64_mask(layer, bit6);
        _mm512_storeu_pd(out + i, _mm512_mul_pd(u, lookup128(xt, layer, m4, m5, m6)));
        const __mmask8 hit = _mm512_cmp_pd_mask(_mm512_abs_pd(u), lookup128(rt, layer, m4, m5, m6), _CMP_LT_OQ);
        for (unsigned miss = ~static_cast<unsigned>(hit) & 0xffu; miss; miss &= miss - 1)
            missed[n_missed++] = static_cast<std::uint32_t>(i + static_cast<unsigned>(__builtin_ctz(miss)));
    }
    return fast_pass_scalar(key, i, n, out, missed, n_missed);
}
#endif
}  // namespace

void fill_normals(std::uint64_t key, std::size_t n, double* out, std::uint32_t* missed, bool portable) {
#ifdef FRINGE_ZIGGURAT_AVX512
    const std::size_t n_missed =
        portable ? fast_pass_scalar(key, 0, n, out, missed, 0) : fast_pass_avx512(key, n, out, missed);
#else
    (void)portable;
    const std::size_t n_missed = fast_pass_scalar(key, 0, n, out, missed, 0);
#endif
    for (std::size_t j = 0; j < n_missed; ++j) {  // ~1 % of draws: finish the ziggurat
        const std::size_t i = missed[j];
        Xoshiro256pp rng(mix64(key ^ mix64(i + 0x632be59bd9b4e019ULL)));
        out[i] = standard_normal_from(draw_bits(key, i), rng);
    }
}

void NoiseField::load_chunk(std::uint64_t chunk) {
    missed_.resize(buf_.size());
    fill_normals(mix64(seed_ + mix64(chunk)), buf_.size(), buf_.data(), missed_.data());
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
