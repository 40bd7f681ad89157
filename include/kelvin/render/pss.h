#pragma once
// Primary sample space (Kelemen et al. 2002): a path is a deterministic function of the uniform numbers its
// sampler hands out, so a Markov chain over paths can be a chain over those numbers. PrimarySampleSpace is the
// Sampler that reads them from a CoordinateSource (core/coordinates.h):
//   - bind() points the sampler at a source and rewinds it; next_1d()/next_2d() read coordinates in order
//     (for a technique with several sample streams, see sampler.h, each stream reads its interleaved share);
//   - a Markov chain binds the lazily realised states it owns (MarkovChain::source(), mlt/chain.h), which
//     realise a coordinate of a proposal from the current state and the kernel on first read;
//   - bind(std::vector&) reads a plain vector that extends itself lazily: reading a coordinate that does not
//     exist yet appends a uniform draw (the prior) from the sampler's own stream (the bootstrap's states).
// Coordinates live on the torus [0, 1) (see torus_wrap / torus_delta in mlt/mutation.h).
#include <kelvin/core/coordinates.h>
#include <kelvin/core/random.h>
#include <kelvin/render/sampler.h>

#include <algorithm>
#include <vector>

namespace kelvin {

class PrimarySampleSpace final : public Sampler {
public:
    /// `seed`, `stream` key the random stream that extends states lazily. `streams`: how many sample streams
    /// the technique uses (SamplingIntegrator::sample_streams(): 1 for path, SampleStreamCount for bdpt and
    /// mmlt). With one stream every set_stream() draws from the same sequence and coordinates are read in order;
    /// with n, the streams are interleaved pair by pair: draws 2j and 2j + 1 of stream s are coordinates
    /// 2 (j n + s) and 2 (j n + s) + 1, so a coordinate pair (the unit a Markov chain moves, mlt/mutation.h)
    /// never mixes two streams and pair p belongs to stream p % n.
    PrimarySampleSpace(uint64_t seed, uint64_t stream, int streams = 1)
        : m_vector(seed, stream), m_streams(std::clamp(streams, 1, SampleStreamCount)) {}
    PrimarySampleSpace(const PrimarySampleSpace& o)
        : Sampler(o),
          m_vector(o.m_vector),
          m_src(o.m_src == &o.m_vector ? &m_vector : o.m_src),
          m_streams(o.m_streams) {}
    PrimarySampleSpace& operator=(const PrimarySampleSpace&) = delete;

    /// Read `state` from the start of every stream, extending it with uniform draws from this sampler's own
    /// random stream (the vector must outlive the reads).
    void bind(std::vector<double>& state) {
        m_vector.x = &state;
        m_src = &m_vector;
        rewind();
    }
    /// Read the coordinates of `source` from the start of every stream (it must outlive the reads).
    void bind(CoordinateSource& source) {
        m_src = &source;
        rewind();
    }
    /// Coordinates spanned by the reads since bind(): one past the highest index read.
    std::size_t used() const { return m_used; }
    /// Numbers drawn from stream `s` since bind().
    std::size_t drawn(SampleStream s) const { return m_next[m_streams == 1 ? 0 : std::min(int(s), m_streams - 1)]; }
    /// How many interleaved streams the coordinates are split into.
    int streams() const { return m_streams; }

    // Sampler.
    long long sample_count() const override { return 1; }
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<PrimarySampleSpace>(*this); }
    /// Ignores its arguments: a PSS sampler is positioned by bind(), not by pixel and index.
    void start(Vec2i, uint64_t, uint64_t) override { rewind(); }
    void set_stream(SampleStream s) override { m_cur = m_streams == 1 ? 0 : std::min(int(s), m_streams - 1); }
    double next_1d() override { return coordinate(); }
    Vec2d next_2d() override {
        const double a = coordinate();
        return {a, coordinate()};
    }

private:
    void rewind() {
        m_cur = 0;
        m_used = 0;
        for (auto& n : m_next) n = 0;
    }
    double coordinate() {
        const std::size_t k = m_next[m_cur]++;
        const std::size_t i = ((k >> 1) * std::size_t(m_streams) + std::size_t(m_cur)) * 2 + (k & 1);
        m_used = std::max(m_used, i + 1);
        return m_src->at(i);
    }

    /// A vector that extends itself with uniform draws.
    struct VectorSource final : CoordinateSource {
        VectorSource(uint64_t seed, uint64_t stream) : rng(seed, stream) {}
        double at(std::size_t i) override {
            while (x->size() <= i) x->push_back(rng.next_double());  // the prior: uniform
            return (*x)[i];
        }
        Random rng;
        std::vector<double>* x = nullptr;
    };

    VectorSource m_vector;
    CoordinateSource* m_src = nullptr;
    int m_streams = 1, m_cur = 0;
    std::size_t m_next[SampleStreamCount] = {0, 0, 0};
    std::size_t m_used = 0;
};

}  // namespace kelvin
