// sobol: a low-discrepancy sampler: the two-dimensional Sobol (0,2)-sequence, Owen-scrambled with a hash, padded
// to any number of dimensions by shuffling the sample index independently for every pixel and dimension.
//
// Construction (Burley 2020, "Practical Hash-based Owen Scrambling", JCGT 9(4); the padding of pbrt-v4's
// PaddedSobolSampler, Pharr, Jakob and Humphreys 2023, Sec. 8.7):
//   - every next_2d() returns a point of the 2D Sobol sequence (Sobol 1967): coordinate 0 is the van der Corput
//     radical inverse in base 2 (bit reversal), coordinate 1 uses the second Sobol generator matrix, the upper
//     triangular Pascal matrix mod 2 (direction numbers v_1 = 1/2, v_k = v_{k-1} xor v_{k-1}/2);
//     together they form a (0,2)-sequence: any aligned block of 2^m consecutive points is a (0,m,2)-net, with
//     exactly one point in every elementary interval of area 2^-m (shapes 2^-a x 2^-(m-a), all a);
//   - the sample index is first shuffled by a nested uniform (Owen) scramble of its bits seeded by (seed,
//     pixel, dimension): the first 2^m indices of a pixel map to one aligned block of 2^m indices, in a random
//     order, so each dimension pair of a pixel is a (0,m,2)-net that is independent of every other pair;
//   - each coordinate is then Owen-scrambled (Owen 1995) with its own seed: a hash applied in the bit-reversed
//     domain whose output bit k depends only on input bits 0..k (Laine and Karras 2011; the hash constants
//     are those of Vegdahl 2021, "Building a Better LK Hash"). Owen scrambling keeps the net property and
//     makes every point uniformly distributed, so estimates stay unbiased;
//   - next_1d() is the van der Corput sequence with its own shuffle and scramble.
// For a smooth integrand the error of a pixel estimate falls like N^-1.5 (Owen 1997) instead of N^-0.5.
//
// Dimensions are counted as the PSS layout counts them (next_1d takes one, next_2d two, per sample stream,
// interleaved across streams as in sampler.h), and every number depends only on (seed, pixel, sample index,
// stream, dimension): like `independent`, any sample can be reproduced
// alone and the image does not depend on the thread count. The net property holds for the first 2^m samples
// of a pixel, so sample counts that are powers of two are best; other counts are allowed (a warning says so).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <sampler type="sobol"><integer name="sample_count" value="64"/></sampler>
#include <kelvin/core/logging.h>
#include <kelvin/core/random.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/sampler.h>

#include <bit>

namespace kelvin {
namespace {

constexpr uint32_t reverse_bits(uint32_t v) {
    v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
    v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
    v = ((v >> 4) & 0x0f0f0f0fu) | ((v & 0x0f0f0f0fu) << 4);
    v = ((v >> 8) & 0x00ff00ffu) | ((v & 0x00ff00ffu) << 8);
    return (v >> 16) | (v << 16);
}

/// Coordinate 1 of the 2D Sobol sequence as a 32-bit fraction: the xor of the direction numbers of the set
/// bits of i. Column k of the Pascal matrix mod 2 is v_k = v_{k-1} ^ (v_{k-1} >> 1), v_0 = 2^31.
constexpr uint32_t sobol_second(uint32_t i) {
    uint32_t r = 0;
    for (uint32_t v = 1u << 31; i != 0; i >>= 1, v ^= v >> 1)
        if (i & 1u) r ^= v;
    return r;
}

/// A bijection of 32-bit words in which output bit k depends only on input bits 0..k and the seed: adding,
/// multiplying by an odd number, and xoring with a multiple by an even number all carry information upwards
/// only. Applied to bit-reversed values it permutes each binary digit depending on the digits before it,
/// which is Owen's nested uniform scrambling (Laine and Karras 2011; constants from Vegdahl 2021).
constexpr uint32_t lk_permutation(uint32_t x, uint32_t seed) {
    x ^= x * 0x3d20adeau;
    x += seed;
    x *= (seed >> 16) | 1u;
    x ^= x * 0x05526c56u;
    x ^= x * 0x53a22864u;
    return x;
}

/// Owen scrambling of a 32-bit fraction (bit 31 is the first binary digit).
constexpr uint32_t owen_scramble(uint32_t v, uint32_t seed) {
    return reverse_bits(lk_permutation(reverse_bits(v), seed));
}

/// Shuffle of a sample index: the same nested scramble applied to the index's bits from the least significant
/// one up, so indices [0, 2^m) map onto one aligned block [c 2^m, (c + 1) 2^m) of the sequence.
constexpr uint32_t shuffle_index(uint32_t index, uint32_t seed) { return owen_scramble(index, seed); }

constexpr double to_unit(uint32_t v) { return double(v) * 0x1p-32; }  // in [0, 1 - 2^-32]

class Sobol final : public Sampler {
public:
    explicit Sobol(const Properties& props)
        : m_count(props.get_int("sample_count", 1, 1LL << 40)), m_seed(uint64_t(props.get_int("seed"))) {
        if (!std::has_single_bit(uint64_t(m_count)))
            log_warn(
                "sampler 'sobol': sample_count {} is not a power of two; the first 2^m samples of a pixel are "
                "the best stratified, so {} or {} would converge better",
                m_count, std::bit_floor(uint64_t(m_count)), std::bit_ceil(uint64_t(m_count)));
    }
    long long sample_count() const override { return m_count; }
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<Sobol>(*this); }

    void start(Vec2i pixel, uint64_t index, uint64_t seed) override {
        // The upper half of a 64-bit index selects another randomisation, so indices beyond 2^32 stay valid.
        uint64_t key = hash_combine(hash_combine(seed, m_seed), 0x736f626f6cULL);
        key = hash_combine(key, uint64_t(uint32_t(pixel.x)) | (uint64_t(uint32_t(pixel.y)) << 32));
        m_key = hash_combine(key, index >> 32);
        m_index = uint32_t(index);
        for (auto& d : m_dims) d = 0;
        m_stream = 0;
    }
    void set_stream(SampleStream s) override { m_stream = int(s); }
    double next_1d() override {
        const uint64_t h = hash_combine(m_key, dim(1));
        const uint32_t i = shuffle_index(m_index, uint32_t(h));
        return to_unit(owen_scramble(reverse_bits(i), uint32_t(h >> 32)));
    }
    Vec2d next_2d() override {
        const uint64_t h = hash_combine(m_key, dim(2));
        const uint64_t h2 = hash_combine(h, 0x32ULL);
        const uint32_t i = shuffle_index(m_index, uint32_t(h));
        return {to_unit(owen_scramble(reverse_bits(i), uint32_t(h >> 32))),
                to_unit(owen_scramble(sobol_second(i), uint32_t(h2)))};
    }

private:
    long long m_count;
    uint64_t m_seed;
    uint64_t m_key = 0;
    uint32_t m_index = 0;
    uint64_t m_dims[SampleStreamCount] = {0, 0, 0};  // dimensions drawn per sample stream
    int m_stream = 0;

    /// The dimension of the next draw (consuming `n`): stream s's dimensions are interleaved like the primary
    /// sample space's (k * streams + s), so the camera stream alone counts 0, 3, 6, ... and stays stable.
    uint64_t dim(int n) {
        const uint64_t d = m_dims[m_stream] * SampleStreamCount + uint64_t(m_stream);
        m_dims[m_stream] += uint64_t(n);
        return d;
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Sobol, "sampler", "sobol",
              "Owen-scrambled Sobol (0,2)-sequence, padded per dimension pair (Burley 2020); powers of two best.",
              kelvin::param::integer("sample_count", 16,
                                     "samples per pixel (--spp overrides it; powers of two are best)"),
              kelvin::param::integer("seed", 0, "seed offset, mixed with the run's --seed"));
