// independent: uniform, independent random numbers (PCG32). Sample k of pixel (x, y) in a run with seed s
// draws from its own PCG32 stream keyed by (s, seed, x, y, k), so any pixel sample can be reproduced alone; the
// light and connection sample streams (SampleStream) are further PCG32 streams keyed by the same and the stream.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <sampler type="independent"><integer name="sample_count" value="64"/></sampler>
#include <kelvin/core/random.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/sampler.h>

namespace kelvin {
namespace {

class Independent final : public Sampler {
public:
    explicit Independent(const Properties& props)
        : m_count(props.get_int("sample_count", 1, 1LL << 40)), m_seed(uint64_t(props.get_int("seed"))) {}
    long long sample_count() const override { return m_count; }
    std::unique_ptr<Sampler> clone() const override {
        auto c = std::make_unique<Independent>(*this);
        c->m_cur = &c->m_rng[m_cur - m_rng];  // point into the copy's own streams
        return c;
    }
    void start(Vec2i pixel, uint64_t index, uint64_t seed) override {
        m_stream = hash_combine(hash_combine(uint64_t(uint32_t(pixel.x)), uint64_t(uint32_t(pixel.y))), index);
        m_key = hash_combine(seed, m_seed);
        m_rng[0].seed_stream(m_key, m_stream);
        m_seeded = 1;  // the light and connection streams are seeded when first used (path never uses them)
        m_cur = &m_rng[0];
    }
    void set_stream(SampleStream s) override {
        const int i = int(s);
        if (!(m_seeded & (1u << i))) {
            m_rng[i].seed_stream(m_key, hash_combine(m_stream, uint64_t(i)));
            m_seeded |= 1u << i;
        }
        m_cur = &m_rng[i];
    }
    double next_1d() override { return m_cur->next_double(); }
    Vec2d next_2d() override { return m_cur->next_2d(); }

private:
    long long m_count;
    uint64_t m_seed;
    Random m_rng[SampleStreamCount];
    Random* m_cur = &m_rng[0];
    uint64_t m_key = 0, m_stream = 0;  // of the current sample
    unsigned m_seeded = 0;             // bit s: stream s is seeded for the current sample
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Independent, "sampler", "independent", "Independent uniform random numbers (PCG32).",
              kelvin::param::integer("sample_count", 4, "samples per pixel"),
              kelvin::param::integer("seed", 0, "seed offset, mixed with the run's --seed"));
