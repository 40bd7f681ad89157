// ldsampler: Mitsuba 3's low-discrepancy sampler `ldsampler` (Kollig and Keller 2002, "Efficient Multidimensional
// Sampling"): every next_2d is the first N points of the two-dimensional Sobol (0,2)-sequence (van der Corput in
// x, Sobol's second generator in y), randomised by a random digit scramble (xor with a random 32-bit word per
// coordinate, which keeps the net property: one sample in every elementary interval of area 1/N), and with the
// sample order shuffled independently per dimension so that dimension pairs are not correlated; next_1d is the
// scrambled van der Corput sequence with its own shuffle. No jitter: the 1D projections are exactly stratified.
// sample_count is rounded up to a square power of two (4, 16, 64, 256, ...) with a warning, as Mitsuba does.
// Unlike Mitsuba (one scramble per pixel), the scramble is drawn per pixel and dimension. `sobol` is Kelvin's
// Owen-scrambled variant of the same sequence. Determinism and samples beyond N: block_sampler.h.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <sampler type="ldsampler"><integer name="sample_count" value="64"/></sampler>
#include "block_sampler.h"

namespace kelvin {
namespace {

using block_sampler::permute;

constexpr uint32_t reverse_bits32(uint32_t v) {
    v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
    v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
    v = ((v >> 4) & 0x0f0f0f0fu) | ((v & 0x0f0f0f0fu) << 4);
    v = ((v >> 8) & 0x00ff00ffu) | ((v & 0x00ff00ffu) << 8);
    return (v >> 16) | (v << 16);
}

/// Sobol's second coordinate as a 32-bit fraction: direction numbers v_0 = 2^31, v_k = v_{k-1} ^ (v_{k-1} >> 1).
constexpr uint32_t sobol_y(uint32_t i) {
    uint32_t r = 0;
    for (uint32_t v = 1u << 31; i != 0; i >>= 1, v ^= v >> 1)
        if (i & 1u) r ^= v;
    return r;
}

constexpr double frac(uint32_t v) { return double(v) * 0x1p-32; }

class LdSampler final : public block_sampler::PatternSampler {
public:
    explicit LdSampler(const Properties& props)
        : PatternSampler(props, "ldsampler", 0x6c6473ULL, false, [](long long n) {
              long long r = 2;
              while (r * r < n) r *= 2;
              return r * r;
          }) {}
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<LdSampler>(*this); }
    double next_1d() override {
        const uint64_t d = next_dimension();
        const uint32_t i = permute(index(), count(), dim_seed(d, 0));
        return frac(reverse_bits32(i) ^ dim_seed(d, 1));
    }
    Vec2d next_2d() override {
        const uint64_t d = next_dimension();
        const uint32_t i = permute(index(), count(), dim_seed(d, 0));
        return {frac(reverse_bits32(i) ^ dim_seed(d, 1)), frac(sobol_y(i) ^ dim_seed(d, 2))};
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::LdSampler, "sampler", "ldsampler",
              "Scrambled (0,2)-sequence, shuffled per dimension (Kollig and Keller 2002; Mitsuba's ldsampler).",
              kelvin::param::integer("sample_count", 4, "samples per pixel, rounded up to a square power of two"),
              kelvin::param::integer("seed", 0, "seed offset, mixed with the run's --seed"));
