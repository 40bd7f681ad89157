// stratified: jittered stratified sampling (Mitsuba 3's `stratified`). Every dimension is stratified on its
// own: next_1d puts one sample in each of N intervals [i/N, (i+1)/N), next_2d one in each cell of an
// r x r grid (N = r^2), each in an order shuffled by a permutation of its own (per pixel, dimension and
// stream), with a uniform jitter inside the stratum (or the stratum's centre with jitter off).
// sample_count is rounded up to the next square, with a warning, as Mitsuba does (5 -> 9).
// Determinism and samples beyond N: block_sampler.h.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <sampler type="stratified"><integer name="sample_count" value="16"/></sampler>
#include "block_sampler.h"

namespace kelvin {
namespace {

using block_sampler::permute;

class Stratified final : public block_sampler::PatternSampler {
public:
    explicit Stratified(const Properties& props)
        : PatternSampler(props, "stratified", 0x7374726174ULL, true, [](long long n) {
              long long r = 1;
              while (r * r < n) ++r;
              return r * r;
          }) {
        m_res = 1;
        while (m_res * m_res < count()) ++m_res;
    }
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<Stratified>(*this); }
    double next_1d() override { return stratified_1d(); }
    Vec2d next_2d() override {
        const uint64_t d = next_dimension();
        const uint32_t p = permute(index(), count(), dim_seed(d, 0));
        const uint32_t x = p % m_res, y = p / m_res;
        return {(x + jitter(d, 0)) / m_res, (y + jitter(d, 1)) / m_res};
    }

private:
    uint32_t m_res = 1;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Stratified, "sampler", "stratified",
              "Jittered stratified samples, shuffled per dimension (Mitsuba's stratified); count rounded to a square.",
              kelvin::param::integer("sample_count", 4, "samples per pixel, rounded up to a square"),
              kelvin::param::integer("seed", 0, "seed offset, mixed with the run's --seed"),
              kelvin::param::boolean("jitter", true, "jitter inside each stratum (false: stratum centres)"));
