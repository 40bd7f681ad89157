#pragma once
// Primary sample space (Kelemen et al. 2002): a path is a deterministic function of the uniform numbers its
// sampler hands out, so a Markov chain over paths can be a chain over those numbers. PrimarySampleSpace is the
// Sampler that reads them from a state vector a Markov chain owns (MarkovChain keeps the accepted state x and
// its proposals y, z side by side, which is its backup/restore; proposals are Mutation plugins):
//   - bind() points the sampler at a state and rewinds it; next_1d()/next_2d() read coordinates in order;
//   - the vector is extended lazily: reading a coordinate that does not exist yet appends a uniform draw (the
//     prior) from the sampler's own stream, so paths of any length work and unread coordinates cost nothing.
// Coordinates live on the torus [0, 1) (see torus_wrap / torus_delta in mlt/mutation.h).
#include <kelvin/core/random.h>
#include <kelvin/render/sampler.h>

#include <vector>

namespace kelvin {

class PrimarySampleSpace final : public Sampler {
public:
    /// `seed`, `stream` key the stream that extends states lazily.
    PrimarySampleSpace(uint64_t seed, uint64_t stream) : m_rng(seed, stream) {}

    /// Read `state` from dimension 0 (the vector must outlive the reads).
    void bind(std::vector<double>& state) {
        m_x = &state;
        m_next = 0;
    }
    /// Dimensions read since bind().
    std::size_t used() const { return m_next; }

    // Sampler.
    long long sample_count() const override { return 1; }
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<PrimarySampleSpace>(*this); }
    /// Ignores its arguments: a PSS sampler is positioned by bind(), not by pixel and index.
    void start(Vec2i, uint64_t, uint64_t) override { m_next = 0; }
    double next_1d() override { return coordinate(m_next++); }
    Vec2d next_2d() override {
        const double a = coordinate(m_next++);
        return {a, coordinate(m_next++)};
    }

private:
    double coordinate(std::size_t i) {
        std::vector<double>& x = *m_x;
        while (x.size() <= i) x.push_back(m_rng.next_double());  // the prior: uniform
        return x[i];
    }

    Random m_rng;
    std::vector<double>* m_x = nullptr;
    std::size_t m_next = 0;
};

}  // namespace kelvin
