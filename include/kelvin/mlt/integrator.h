#pragma once
// Primary-sample-space Metropolis light transport with optional two-stage delayed rejection: the `pssmlt` and
// `drmlt` integrators (Kelemen et al. 2002; thesis Ch. 4 and Appendix B; Rioux-Lavoie, Litalien et al., ACM
// TOG 39(3), 2020). Parameters and the estimator are documented in docs/mlt.md.
//
// The chains run over a path sampler (`path` or `bdpt`) driven through PrimarySampleSpace, or over one
// bidirectional strategy per state (`mmlt`, multiplexed MLT: Hachisuka et al. 2014; thesis Sec. 4.3.1.2). A state x is
// the vector of primary samples; its contribution F(x) is a list of (film position, RGB) pairs: the camera subpath's
// estimate at the film position the state's first two coordinates choose, and (bdpt) the light-tracing strategies at
// theirs. The target is pi(x) = sum of the luminances. With b = E_uniform[pi] (bootstrap), the image is  I_j = b / N
// sum over steps and states s of  w_s  sum_c h_j(p_c) F_c(s) / pi(s), with w_s the waste-recycling weights of the step
// (or 1 for the state the chain is in, without recycling).
#include <kelvin/mlt/chain.h>
#include <kelvin/render/integrator.h>

#include <memory>
#include <mutex>

namespace kelvin {
class PathDerivatives;
}

namespace kelvin {

/// Multiplexed MLT (technique mmlt): what the chains of one path length did.
struct MmltDepthStatistics {
    int edges = 0;             ///< path length (edges) of this depth's chains
    double normalization = 0;  ///< b_k: the bootstrap's mean target value at this length
    uint64_t chains = 0;       ///< chains given to this length
    uint64_t steps = 0;        ///< mutations made by them
    /// Per strategy s = 0..edges (t = edges + 1 - s): small steps proposed and accepted while the state used s,
    /// second stages attempted and accepted.
    std::vector<uint64_t> small_steps, small_accepted, stage2_attempted, stage2_accepted;
};

/// What a Metropolis render did, available after render() and printed with the run's statistics.
struct MltStatistics {
    ChainStats chain;          ///< summed over chains
    double normalization = 0;  ///< b, estimated (bootstrap) or given
    uint64_t bootstrap_samples = 0;
    uint64_t bootstrap_nonzero = 0;  ///< bootstrap paths with pi > 0
    uint64_t chains = 0;
    uint64_t invalid_contributions = 0;  ///< NaN, Inf or negative path values recorded as zero
    uint64_t splat_overflow = 0;         ///< splats dropped as out of range (should stay 0)
    double seconds_bootstrap = 0, seconds_direct = 0, seconds_chains = 0;
    double mutations_per_pixel = 0;
    std::vector<MmltDepthStatistics> depths;  ///< technique mmlt: per path length
    /// technique mmlt: rays traced for camera subpaths, light subpaths and connections, over all evaluations;
    /// light-subpath rays traced while evaluating second-stage proposals of states with t >= 2, whose light
    /// subpath the second stage keeps (0: they are reused, not re-traced), and the proposals that reused it.
    uint64_t rays_camera = 0, rays_light = 0, rays_connection = 0, rays_light_stage2 = 0, light_subpaths_reused = 0;
    /// technique mmlt: small steps after which the state's strategy differed from before (must stay 0).
    uint64_t mmlt_strategy_changes_small = 0;

    double stage1_acceptance() const {
        return rate(chain.stage1_accepted - chain.large_accepted,
                    chain.steps - chain.large_steps - chain.mixture_second);
    }
    double large_step_acceptance() const { return rate(chain.large_accepted, chain.large_steps); }
    double stage2_acceptance() const { return rate(chain.stage2_accepted, chain.stage2_attempted); }
    double mutations_per_second() const { return seconds_chains > 0 ? double(chain.steps) / seconds_chains : 0.0; }
    /// Share of the chains' step time spent in the second stage: sampling z (and y*), evaluating them, the
    /// densities and the decision (measured by the chains on every 16th step).
    double stage2_time_share() const {
        const double t = chain.seconds_stage1 + chain.seconds_stage2;
        return t > 0 ? chain.seconds_stage2 / t : 0.0;
    }

private:
    static double rate(uint64_t a, uint64_t n) { return n > 0 ? double(a) / double(n) : 0.0; }
};

/// chains = -1: ceil(mutations / mutations_per_chain) chains, clamped to [MinAutoChains, MaxAutoChains] (at
/// least enough units of work for any thread count to stay busy; docs/mlt.md, "How many chains").
inline constexpr long long MinAutoChains = 64, MaxAutoChains = 4096;
long long auto_chain_count(double mutations, double mutations_per_chain);

/// The steps chain `c` of `chains` has made once `total` steps are made by all of them: step k of the run belongs
/// to chain k mod chains (round robin), so every chain's count never decreases as `total` grows, the counts sum
/// to `total` and differ by at most one. A pass from total a to b gives chain c chain_steps(b, c, C) -
/// chain_steps(a, c, C) >= 0 steps, whatever the pass sizes, the chain count and the pixel count.
constexpr uint64_t chain_steps(unsigned __int128 total, uint64_t c, uint64_t chains) {
    if (total <= c) return 0;
    return uint64_t((total - 1 - c) / chains + 1);
}

class MetropolisIntegrator : public Integrator {
public:
    /// `delayed_rejection`: read the parameters of `drmlt` (type, first/second) rather than `pssmlt`'s.
    MetropolisIntegrator(const Properties& props, bool delayed_rejection);
    ~MetropolisIntegrator() override;
    bool distributable() const override { return true; }

    RunResult render(const Scene& scene, RunContext& ctx) override;
    /// "drmlt (orbital, Tierney–Mira)": the plugin, its mutation(s) and, for drmlt, the delayed-rejection type.
    std::string description() const override;
    /// The statistics of the last render() (thread-safe to read after it returns).
    MltStatistics statistics() const;

    DrType type() const { return m_config.type; }
    const Mutation& first_stage() const { return *m_first; }
    const Mutation* second_stage() const { return m_second.get(); }

private:
    class Render;  // one render()'s steps and state (integrator.cpp)
    std::shared_ptr<Mutation> m_first, m_second;
    ChainConfig m_config;
    std::shared_ptr<SamplingIntegrator> m_technique, m_direct;  // the path sampler; the direct-lighting renderer
    bool m_delayed_rejection;
    bool m_mmlt = false;  // technique mmlt: one bidirectional strategy per state, chains per path length
    int m_min_edges = 1, m_max_edges = -1;
    bool m_hide_emitters = false;
    int m_rr_depth = 5;
    bool m_local = false;  // a kernel has local proposals (h2mc): the chains get the path's derivatives
    int m_warmup = 0;      // an adaptive local kernel's warm-up steps per chain (langevin), from an independent start
    std::unique_ptr<PathDerivatives> m_derivatives;  // built per render when m_local
    SourceLoc m_technique_loc;
    bool m_waste_recycling;
    long long m_bootstrap_samples, m_chains, m_direct_samples;
    double m_mutations_per_pixel, m_normalization, m_mutations_per_chain;
    mutable std::mutex m_stats_mutex;
    MltStatistics m_stats;
};

}  // namespace kelvin
