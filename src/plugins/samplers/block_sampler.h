#pragma once
// Shared by Mitsuba's stratified-family samplers (stratified, multijitter, orthogonal, ldsampler): a pattern of N
// samples per pixel whose sample order is shuffled independently for every dimension, plus optional jitter.
//
// Determinism (as `independent` and `sobol`): every number depends only on (run seed, sampler seed, pixel,
// sample index, stream, dimension), never on the thread or the order of rendering. Sample index k of a pixel
// is sample k mod N of pattern block k / N; each block is a fresh randomisation of the pattern, so a render
// with more samples than N (--spp, equal-time runs) is a sequence of complete, independent patterns (and
// samples 0..N-1 are the scene's N-sample pattern). A "dimension" is one next_1d or next_2d call in a stream,
// as in Mitsuba (its m_dimension_index); streams count their dimensions separately.
#include <kelvin/core/logging.h>
#include <kelvin/core/random.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/sampler.h>

#include <cstdint>

namespace kelvin::block_sampler {

/// A pseudo-random permutation of [0, n) keyed by `seed`, evaluated at i < n: a bijection of the
/// words of w bits (2^w >= n) iterated until it lands below n ("cycle walking"; the construction of Kensler
/// 2013, "Correlated Multi-Jittered Sampling", with our own mixing steps). Every step is invertible modulo
/// 2^w: xor with a constant, multiplication by an odd number, xor with a right shift of itself, addition.
inline uint32_t permute(uint32_t i, uint32_t n, uint32_t seed) {
    if (n <= 1) return 0;
    uint32_t mask = n - 1;
    mask |= mask >> 1;
    mask |= mask >> 2;
    mask |= mask >> 4;
    mask |= mask >> 8;
    mask |= mask >> 16;
    int bits = 0;
    while ((mask >> bits) != 0) ++bits;
    const int s1 = std::max(1, bits / 2), s2 = std::max(1, (bits + 2) / 3);
    do {
        i ^= seed & mask;
        i = (i * 0x9e3779b1u) & mask;
        i ^= i >> s1;
        i = (i + (seed >> 8)) & mask;
        i = (i * (((seed >> 16) * 2u + 1u) | 1u)) & mask;
        i ^= i >> s2;
        i = (i * 0x85ebca6bu) & mask;
        i ^= (i & mask) >> s1;
        i = (i + 0x68e31da4u) & mask;
    } while (i >= n);
    return i;
}

/// Uniform in [0, 1) from a 64-bit hash.
inline double to_unit(uint64_t h) { return double(h >> 11) * 0x1p-53; }

/// The bookkeeping of a pattern sampler; subclasses implement next_1d and next_2d with the helpers.
class PatternSampler : public Sampler {
public:
    long long sample_count() const override { return m_count; }
    void start(Vec2i pixel, uint64_t index, uint64_t seed) override {
        uint64_t key = hash_combine(hash_combine(seed, m_seed), m_tag);
        key = hash_combine(key, uint64_t(uint32_t(pixel.x)) | (uint64_t(uint32_t(pixel.y)) << 32));
        m_key = hash_combine(key, index / uint64_t(m_count));  // the pattern block
        m_index = uint32_t(index % uint64_t(m_count));         // the sample within it
        m_sample_key = hash_combine(m_key, uint64_t(m_index) ^ 0x6a09e667f3bcc909ULL);
        for (auto& d : m_dims) d = 0;
        m_stream = 0;
    }
    void set_stream(SampleStream s) override { m_stream = int(s); }

protected:
    /// Reads sample_count (rounded by the subclass through `round`), seed and, if `has_jitter`, jitter.
    template <typename Round>
    PatternSampler(const Properties& props, const char* name, uint64_t tag, bool has_jitter, Round round)
        : m_seed(uint64_t(props.get_int("seed"))), m_tag(tag) {
        const long long asked = props.get_int("sample_count", 1, 1LL << 30);
        m_count = round(asked);
        if (m_count != asked)
            log_warn("sampler '{}': sample_count {} rounded to {}, as Mitsuba does", name, asked, m_count);
        m_jitter = has_jitter ? props.get_bool("jitter") : false;
    }

    /// The next dimension of the current stream (one per next_1d / next_2d call).
    uint64_t next_dimension() { return m_dims[m_stream]++; }
    /// A 32-bit seed for dimension `d` of the current stream and pixel block, for permutation `which`.
    uint32_t dim_seed(uint64_t d, uint64_t which) const {
        return uint32_t(hash_combine(hash_combine(m_key, (d << 2) | uint64_t(m_stream)), which));
    }
    /// Jitter for dimension `d`, axis `axis` of the current sample: uniform, or 0.5 without jitter.
    double jitter(uint64_t d, int axis) const {
        if (!m_jitter) return 0.5;
        return to_unit(hash_combine(m_sample_key, (d << 3) | (uint64_t(m_stream) << 1) | uint64_t(axis)));
    }
    /// One sample in each of the N intervals [i/N, (i+1)/N) of the next dimension, the order shuffled per dimension
    /// (stratified and multijitter's next_1d).
    double stratified_1d() {
        const uint64_t d = next_dimension();
        return (permute(m_index, uint32_t(m_count), dim_seed(d, 0)) + jitter(d, 0)) / double(m_count);
    }
    /// The current sample's index within its block, and the block size N.
    uint32_t index() const { return m_index; }
    int current_stream() const { return m_stream; }
    uint32_t count() const { return uint32_t(m_count); }

private:
    long long m_count = 1;
    uint64_t m_seed = 0, m_tag = 0;
    bool m_jitter = false;
    uint64_t m_key = 0, m_sample_key = 0;
    uint32_t m_index = 0;
    uint64_t m_dims[SampleStreamCount] = {0, 0, 0};
    int m_stream = 0;
};

}  // namespace kelvin::block_sampler
