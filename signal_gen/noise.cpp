#include "noise.hpp"

#include <cmath>
#include <cstring>

#if defined(__AVX512F__) && defined(__AVX512DQ__)
#include <immintrin.h>
#define FRINGE_ZIGGURAT_AVX512 1
#endif

namespace fringe {

namespace {
constexpr std::uint64_t kGamma = 0x9e3779b97f4a7c15ULL;  // splitmix64's Weyl increment
}

Xoshiro256pp::Xoshiro256pp(std::uint64_t seed) {
    std::uint64_t z = seed;
    for (auto& s : s_) {
        z += kGamma;
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
    // The wedge's squeeze: on layer i's wedge (x[i+1] <= |x| <= x[i]) the density lies between
    // its chord through the layer's edges and its tangent at the wedge's middle (tm = the
    // tangent's value at 0, ts its slope): chord above and tangent below where the density is
    // convex (|x| >= 1), the other way round where it is concave (|x| <= 1). convex: +1, -1
    // concave, 0 a layer across 1 (no squeeze).
    double tm[kLayers], ts[kLayers];
    int convex[kLayers];
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
        for (int i = 0; i < kLayers; ++i) {
            const double m = 0.5 * (x[i] + x[i + 1]), gm = std::exp(-0.5 * m * m);
            ts[i] = -m * gm;       // d/dx exp(-x^2/2) at m
            tm[i] = gm - ts[i] * m;  // the tangent: tm + ts * |x|
            convex[i] = x[i + 1] >= 1.0 ? 1 : (x[i] <= 1.0 ? -1 : 0);
        }
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

// Uniform in (0, 1] from 64 bits.
inline double bits_uniform(std::uint64_t bits) { return (static_cast<double>(bits >> 11) + 1.0) * 0x1p-53; }

template <class Rng>
double normal_tail(Rng& rng, bool negative) {
    double x, y;
    do {
        x = std::log(bits_uniform(rng.next())) / kR;
        y = std::log(bits_uniform(rng.next()));
    } while (-2.0 * y < x * x);
    return negative ? x - kR : kR - x;
}

// The ziggurat continued from a first draw `bits`; further draws from rng.next().
template <class Rng>
double ziggurat_from(std::uint64_t bits, Rng& rng) {
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
        const double y = t.f[i] + bits_uniform(rng.next()) * (t.f[i + 1] - t.f[i]);
        // Most draws are decided by the squeeze, without exp: below both bounds accepted, above
        // both rejected, with a margin (1e-12, against rounding of ~1e-16) so that the decision
        // is always the exact test's; between the bounds, the exact test.
        if (t.convex[i] != 0) {
            const double ax = std::fabs(x);
            const double chord = t.f[i] + (t.f[i + 1] - t.f[i]) * ((t.x[i] - ax) / (t.x[i] - t.x[i + 1]));
            const double tangent = t.tm[i] + t.ts[i] * ax;
            const double lo = t.convex[i] > 0 ? tangent : chord, hi = t.convex[i] > 0 ? chord : tangent;
            constexpr double kMargin = 1e-12;
            if (y < lo - kMargin) return x;
            if (y > hi + kMargin) continue;
        }
        if (y < std::exp(-0.5 * x * x)) return x;
    }
}

// The draws after a missed fast path in fill_normals: splitmix64 of a per-draw seed, so a
// miss costs one hash per extra draw (most need one) instead of seeding a generator.
struct CounterBits {
    std::uint64_t base, j = 0;
    std::uint64_t next() { return mix64(base + (++j) * kGamma); }
};
}  // namespace

double standard_normal(Xoshiro256pp& rng) { return ziggurat_from(rng.next(), rng); }



NoiseField::NoiseField(std::uint64_t seed, std::uint64_t stream_id, int streams)
    : seed_(mix64(seed ^ mix64(stream_id + 0x51ed270b2a1e6f1dULL))), streams_(streams),
      buf_(kNoiseChunk * static_cast<std::size_t>(streams)) {}

namespace {
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
// The same fast path sixteen draws at a time with the tables held in registers, as 32-bit
// words so that one two-source permute covers 32 entries: x[layer] from its high and low
// words (four permutes each, blends on bits 5 and 6 of the layer), and a float copy of
// ratio[layer] rounded down for the acceptance test. Gathers would be simpler but are
// microcoded (slow) on recent Intel cores. A draw the float ratio rejects but the exact one
// accepts just goes to the slow path, which returns the same u * x[layer]; every value is
// computed with the same IEEE operations as fast_pass_scalar, so both paths give identical
// numbers.
struct WordTables {
    alignas(64) std::uint32_t x_hi[kLayers], x_lo[kLayers];
    alignas(64) float ratio_down[kLayers];
    WordTables() {
        const ZigguratTables& t = tables();
        for (int i = 0; i < kLayers; ++i) {
            std::uint64_t w;
            std::memcpy(&w, &t.x[i], sizeof w);
            x_hi[i] = static_cast<std::uint32_t>(w >> 32);
            x_lo[i] = static_cast<std::uint32_t>(w);
            float r = static_cast<float>(t.ratio[i]);
            if (static_cast<double>(r) > t.ratio[i]) r = std::nextafter(r, 0.0f);
            ratio_down[i] = r;
        }
    }
};

// Entry idx (0..127, 16 lanes) of a 128-word table held in eight registers.
inline __m512i lookup128_epi32(const __m512i* tab, __m512i idx, __mmask16 b5, __mmask16 b6) {
    const __m512i g0 = _mm512_permutex2var_epi32(tab[0], idx, tab[1]);
    const __m512i g1 = _mm512_permutex2var_epi32(tab[2], idx, tab[3]);
    const __m512i g2 = _mm512_permutex2var_epi32(tab[4], idx, tab[5]);
    const __m512i g3 = _mm512_permutex2var_epi32(tab[6], idx, tab[7]);
    return _mm512_mask_blend_epi32(b6, _mm512_mask_blend_epi32(b5, g0, g1), _mm512_mask_blend_epi32(b5, g2, g3));
}

inline __m512i mix64_epi64(__m512i z, __m512i c1, __m512i c2) {
    z = _mm512_xor_si512(z, _mm512_srli_epi64(z, 30));
    z = _mm512_mullo_epi64(z, c1);
    z = _mm512_xor_si512(z, _mm512_srli_epi64(z, 27));
    z = _mm512_mullo_epi64(z, c2);
    return _mm512_xor_si512(z, _mm512_srli_epi64(z, 31));
}

inline __m512d draw_u_pd(__m512i bits) {
    return _mm512_sub_pd(_mm512_mul_pd(_mm512_cvtepi64_pd(_mm512_srli_epi64(bits, 11)), _mm512_set1_pd(0x1p-52)),
                         _mm512_set1_pd(1.0));
}

std::size_t fast_pass_avx512(std::uint64_t key, std::size_t n, double* out, std::uint32_t* missed) {
    static const WordTables wt;
    __m512i xh[8], xl[8], rt[8];
    for (int j = 0; j < 8; ++j) {
        xh[j] = _mm512_load_si512(wt.x_hi + 16 * j);
        xl[j] = _mm512_load_si512(wt.x_lo + 16 * j);
        rt[j] = _mm512_castps_si512(_mm512_load_ps(wt.ratio_down + 16 * j));
    }
    const __m512i c1 = _mm512_set1_epi64(static_cast<long long>(0xbf58476d1ce4e5b9ULL));
    const __m512i c2 = _mm512_set1_epi64(static_cast<long long>(0x94d049bb133111ebULL));
    const __m512i step = _mm512_set1_epi64(static_cast<long long>(16 * kGamma));
    const __m512i low_words = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
    const __m512i join_lo = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
    const __m512i join_hi = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
    const __m512i layer_mask = _mm512_set1_epi32(kLayers - 1);
    const __m512i bit5 = _mm512_set1_epi32(32), bit6 = _mm512_set1_epi32(64);
    const __m512i gamma = _mm512_set1_epi64(static_cast<long long>(kGamma));
    const __m512i lane_index = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    // Lane l of z0 holds key + (i + l + 1) * gamma, of z1 key + (i + l + 9) * gamma
    // (wrapping arithmetic, as in draw_bits).
    __m512i z0 = _mm512_add_epi64(_mm512_set1_epi64(static_cast<long long>(key)),
                                  _mm512_mullo_epi64(_mm512_setr_epi64(1, 2, 3, 4, 5, 6, 7, 8), gamma));
    __m512i z1 = _mm512_add_epi64(z0, _mm512_mullo_epi64(_mm512_set1_epi64(8), gamma));
    std::size_t n_missed = 0, i = 0;
    for (; i + 16 <= n; i += 16, z0 = _mm512_add_epi64(z0, step), z1 = _mm512_add_epi64(z1, step)) {
        const __m512i b0 = mix64_epi64(z0, c1, c2), b1 = mix64_epi64(z1, c1, c2);
        const __m512i layer = _mm512_and_si512(_mm512_permutex2var_epi32(b0, low_words, b1), layer_mask);
        const __mmask16 m5 = _mm512_test_epi32_mask(layer, bit5), m6 = _mm512_test_epi32_mask(layer, bit6);
        const __m512i hi = lookup128_epi32(xh, layer, m5, m6), lo = lookup128_epi32(xl, layer, m5, m6);
        const __m512d x0 = _mm512_castsi512_pd(_mm512_permutex2var_epi32(lo, join_lo, hi));
        const __m512d x1 = _mm512_castsi512_pd(_mm512_permutex2var_epi32(lo, join_hi, hi));
        const __m512 r = _mm512_castsi512_ps(lookup128_epi32(rt, layer, m5, m6));
        const __m512d r0 = _mm512_cvtps_pd(_mm512_castps512_ps256(r));
        const __m512d r1 = _mm512_cvtps_pd(_mm512_extractf32x8_ps(r, 1));
        const __m512d u0 = draw_u_pd(b0), u1 = draw_u_pd(b1);
        _mm512_storeu_pd(out + i, _mm512_mul_pd(u0, x0));
        _mm512_storeu_pd(out + i + 8, _mm512_mul_pd(u1, x1));
        const unsigned hit = static_cast<unsigned>(_mm512_cmp_pd_mask(_mm512_abs_pd(u0), r0, _CMP_LT_OQ)) |
                             static_cast<unsigned>(_mm512_cmp_pd_mask(_mm512_abs_pd(u1), r1, _CMP_LT_OQ)) << 8;
        // The missed draws' indices, compressed to the front of a register and stored whole
        // (no branch per miss: about a third of the groups of 16 have one). The store's tail
        // lies within missed[0, i + 16), which is overwritten later or not read.
        const __mmask16 miss = static_cast<__mmask16>(~hit & 0xffffu);
        const __m512i idx = _mm512_add_epi32(_mm512_set1_epi32(static_cast<int>(i)), lane_index);
        _mm512_storeu_si512(missed + n_missed, _mm512_maskz_compress_epi32(miss, idx));
        n_missed += static_cast<std::size_t>(__builtin_popcount(miss));
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
    // 2.8 % of draws (1 - mean ratio over the layers; the top layer always) finish the
    // ziggurat with further bits from splitmix64 at miss_key + i*K + j*gamma, j = 1, 2, ...:
    // one hash per extra draw, none to seed.
    const std::uint64_t miss_key = mix64(key ^ 0x632be59bd9b4e019ULL);
    for (std::size_t j = 0; j < n_missed; ++j) {
        const std::size_t i = missed[j];
        CounterBits rng{miss_key + i * 0xd1342543de82ef95ULL};
        out[i] = ziggurat_from(draw_bits(key, i), rng);
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
