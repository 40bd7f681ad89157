#pragma once
// Primary sample space (Kelemen et al. 2002): a path is a deterministic function of the uniform numbers its
// sampler hands out, so a Markov chain over paths can be a chain over those numbers. PrimarySampleSpace is a
// Sampler whose numbers are the coordinates of a state vector that the chain owns:
//   - the vector is extended lazily: reading a coordinate that does not exist yet draws it uniformly (the
//     prior), so paths of any length work and unread coordinates cost nothing;
//   - proposals change the vector in place (a mutation hook gets the whole vector and the chain's random
//     stream), the path is re-evaluated from dimension 0 with restart(), and the chain then accepts (the
//     proposal becomes the state) or rejects (the last accepted state is restored exactly);
//   - large steps (independent proposals) replace every coordinate by a fresh uniform draw, lazily.
// Coordinates live on the torus [0, 1): mutations wrap (see wrap()).
#include <kelvin/core/random.h>
#include <kelvin/render/sampler.h>

#include <functional>
#include <vector>

namespace kelvin {

class PrimarySampleSpace final : public Sampler {
public:
    /// A proposal kernel: changes `x` (already holding the current state's materialised coordinates) in place.
    using Mutation = std::function<void(std::vector<double>& x, Random& rng)>;

    /// `rng` feeds lazy extension and large steps; the chain keeps its own stream for accept/reject.
    PrimarySampleSpace(uint64_t seed, uint64_t stream);

    // Sampler: numbers come from the state vector, in order, from the last restart().
    long long sample_count() const override { return 1; }
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<PrimarySampleSpace>(*this); }
    /// Ignores its arguments: a PSS sampler is positioned by the chain, not by pixel and index.
    void start(Vec2i, uint64_t, uint64_t) override { restart(); }
    double next_1d() override { return coordinate(m_next++); }
    Vec2d next_2d() override {
        double a = coordinate(m_next++);
        return {a, coordinate(m_next++)};
    }

    /// Read from dimension 0 again (before evaluating a path).
    void restart() { m_next = 0; }
    /// Dimensions the last evaluation read.
    std::size_t used() const { return m_next; }
    /// Materialised coordinates of the proposal (or of the state, outside a proposal).
    const std::vector<double>& values() const { return m_x; }
    double coordinate(std::size_t i);

    /// Begin a proposal from the accepted state: `mutate` perturbs the materialised coordinates.
    void propose(const Mutation& mutate);
    /// Begin an independent proposal: every coordinate is redrawn uniformly (lazily, on first read).
    void propose_large_step();
    /// The proposal becomes the state.
    void accept();
    /// Back to the last accepted state, exactly.
    void reject();
    bool in_proposal() const { return m_in_proposal; }

    /// x mod 1 in [0, 1), also for negative x (toroidal wrapping of the primary sample space).
    static double wrap(double x);

private:
    Random m_rng;
    std::vector<double> m_x, m_backup;
    std::size_t m_backup_size = 0;  // coordinates materialised when the proposal began
    std::size_t m_next = 0;
    bool m_large = false, m_in_proposal = false;
    std::vector<uint8_t> m_redrawn;  // large step: which coordinates have been redrawn already
};

}  // namespace kelvin
