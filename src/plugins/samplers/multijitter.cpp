// multijitter: correlated multi-jittered sampling (Kensler 2013, "Correlated Multi-Jittered Sampling", Pixar
// technical memo 13-01), Mitsuba 3's `multijitter` in two dimensions. The N = X * Y samples of next_2d lie one
// in each cell of an X x Y grid and, at the same time, one in each of the N columns [i/N, (i+1)/N) and each of
// the N rows: the sample of cell (x, y) sits in sub-column perm_y(y) of its cell and in sub-row perm_x(x), with
// the permutations shared along a row / column (the "correlated" variant). next_1d is stratified into N
// intervals. Orders are shuffled per pixel, dimension and stream; jitter is uniform inside the sub-cell.
// Grid: Y = floor(sqrt(sample_count)), X = ceil(sample_count / Y); the count is rounded up to X * Y with a
// warning (Mitsuba 3's two-dimensional multijitter: 10 -> 12). Determinism and samples beyond N:
// block_sampler.h.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <sampler type="multijitter"><integer name="sample_count" value="64"/></sampler>
#include "block_sampler.h"

#include <cmath>

namespace kelvin {
namespace {

using block_sampler::permute;

std::pair<long long, long long> grid_of(long long n) {
    long long y = (long long)std::floor(std::sqrt(double(n)));
    while (y * y > n) --y;
    while ((y + 1) * (y + 1) <= n) ++y;
    return {(n + y - 1) / y, y};
}

class MultiJitter final : public block_sampler::PatternSampler {
public:
    explicit MultiJitter(const Properties& props)
        : PatternSampler(props, "multijitter", 0x6d6a6974ULL, true, [](long long n) {
              auto [x, y] = grid_of(n);
              return x * y;
          }) {
        auto [x, y] = grid_of(count());
        m_rx = uint32_t(x);
        m_ry = uint32_t(y);
    }
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<MultiJitter>(*this); }
    double next_1d() override { return stratified_1d(); }
    Vec2d next_2d() override {
        const uint64_t d = next_dimension();
        const uint32_t s = permute(index(), count(), dim_seed(d, 0));
        const uint32_t x = s % m_rx, y = s / m_rx;
        const uint32_t sx = permute(x, m_rx, dim_seed(d, 1)), sy = permute(y, m_ry, dim_seed(d, 2));
        return {(x + (sy + jitter(d, 0)) / m_ry) / m_rx, (y + (sx + jitter(d, 1)) / m_rx) / m_ry};
    }

private:
    uint32_t m_rx = 1, m_ry = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::MultiJitter, "sampler", "multijitter",
              "Correlated multi-jittered samples (Kensler 2013; Mitsuba's multijitter); count rounded up to X * Y.",
              kelvin::param::integer("sample_count", 4, "samples per pixel, rounded up to a near-square grid"),
              kelvin::param::integer("seed", 0, "seed offset, mixed with the run's --seed"),
              kelvin::param::boolean("jitter", true, "jitter inside each sub-cell (false: sub-cell centres)"));
