// orthogonal: orthogonal-array sampling (Jarosz, Enayet, Kensler, Kilpatrick and Christensen 2019, "Orthogonal
// Array Sampling for Monte Carlo Rendering"), Mitsuba 3's `orthogonal` with its default strength 2: Bose's
// construction over a prime p, N = p^2 samples. Sample i (after a shuffle) is the grid point (a0, a1) =
// (i / p, i mod p); column c of the array is a0 for c = 0, a1 for c = 1 and a0 + (c - 1) a1 mod p for
// c = 2..p. Any two columns are orthogonal: every pair of values appears exactly once among the N samples. Each
// next_1d takes one column: its value picks one of p strata, a partner column (c xor 1) the sub-stratum, so
// every dimension is stratified into N intervals (multi-jitter) and every pair of dimensions of one array into a
// p x p grid. next_2d takes two columns of the same array. The array has p + 1 columns; the next dimensions
// use a new, independently shuffled array (Mitsuba keeps indexing columns past p, which repeats slopes).
// sample_count is rounded up to the square of a prime with a warning, as Mitsuba does (10 -> 25).
// Determinism and samples beyond N: block_sampler.h. Only strength 2 is supported (Mitsuba's Bush
// construction for higher strengths is refused).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <sampler type="orthogonal"><integer name="sample_count" value="49"/></sampler>
#include "block_sampler.h"

namespace kelvin {
namespace {

using block_sampler::permute;

bool is_prime(long long x) {
    if (x < 2) return false;
    for (long long i = 2; i * i <= x; ++i)
        if (x % i == 0) return false;
    return true;
}

long long prime_root(long long n) {
    long long p = 2;
    while (p * p < n || !is_prime(p)) ++p;
    return p;
}

class Orthogonal final : public block_sampler::PatternSampler {
public:
    explicit Orthogonal(const Properties& props)
        : PatternSampler(props, "orthogonal", 0x6f7274686fULL, true, [](long long n) {
              const long long p = prime_root(n);
              return p * p;
          }) {
        if (props.get_int("strength") != 2)
            props.error("strength", "only strength 2 (Bose's construction) is supported");
        m_p = uint32_t(prime_root(count()));
    }
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<Orthogonal>(*this); }
    void start(Vec2i pixel, uint64_t index, uint64_t seed) override {
        PatternSampler::start(pixel, index, seed);
        for (auto& c : m_column) c = 0;
        for (auto& a : m_array) a = 0;
    }
    double next_1d() override { return value(take_columns(1)); }
    Vec2d next_2d() override {
        const uint32_t c = take_columns(2);
        return {value(c), value(c + 1)};
    }

private:
    uint32_t m_p = 2;
    // Per stream: the array in use (counted) and its next unused column.
    uint32_t m_column[SampleStreamCount] = {0, 0, 0};
    uint64_t m_array[SampleStreamCount] = {0, 0, 0};
    int m_cur = 0;  // the stream of the last take_columns

    /// Reserve n consecutive columns of one array in the current stream (a new array if fewer are left).
    uint32_t take_columns(uint32_t n) {
        // The stream is identified through next_dimension's own counter: consume one dimension per call so
        // that the base class's per-stream bookkeeping stays meaningful.
        (void)next_dimension();
        m_cur = current_stream();
        if (m_column[m_cur] + n > m_p + 1) {
            ++m_array[m_cur];
            m_column[m_cur] = 0;
        }
        const uint32_t c = m_column[m_cur];
        m_column[m_cur] += n;
        return c;
    }

    /// Column c (0..p) of the current array for the current sample, as a number in [0, 1).
    double value(uint32_t c) {
        const uint64_t a = m_array[m_cur];
        const uint32_t i = permute(index(), count(), dim_seed(a, 0));
        const uint32_t a0 = i / m_p, a1 = i % m_p;
        const uint32_t k = c ^ 1u;
        const uint32_t stratum = permute(column(a0, a1, c), m_p, dim_seed(a, 1 + 2 * uint64_t(c)));
        const uint32_t sub = permute(column(a0, a1, k), m_p, dim_seed(a, 2 + 2 * uint64_t(c)));
        return (stratum + (sub + jitter(hash_combine(a, c), 0)) / m_p) / m_p;
    }
    uint32_t column(uint32_t a0, uint32_t a1, uint32_t c) const {
        if (c == 0) return a0;
        if (c == 1) return a1;
        return uint32_t((uint64_t(a0) + uint64_t(c - 1) * a1) % m_p);
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Orthogonal, "sampler", "orthogonal",
              "Orthogonal-array samples of strength 2 (Bose; Jarosz et al. 2019; Mitsuba's orthogonal).",
              kelvin::param::integer("sample_count", 4, "samples per pixel, rounded up to the square of a prime"),
              kelvin::param::integer("seed", 0, "seed offset, mixed with the run's --seed"),
              kelvin::param::boolean("jitter", true, "jitter inside each sub-stratum (false: centres)"),
              kelvin::param::integer("strength", 2, "orthogonal-array strength; only 2 is supported"));
