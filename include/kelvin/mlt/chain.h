#pragma once
// A Metropolis–Hastings chain with optional two-stage delayed rejection (DR), independent of rendering: the
// target is any non-negative function of a point of the unit torus that reads its coordinates lazily. This is
// the engine of the pssmlt and drmlt integrators (thesis Ch. 4 and Appendix B; Rioux-Lavoie, Litalien et al.
// 2020), tested on analytic targets in tests/mlt.
//
// One step (Algorithm B.1):
//   y ~ Q1(. | x) (or, with probability large_step_prob, y uniform: a large step);
//   a1 = 1 ^ pi(y) / pi(x)                                                              Eq. (4.1), Q1 symmetric
//   if rejected and a second stage is configured (and allowed after a large step):
//     orbital:  z on the orbit of y through x, a2 = 1 ^ (0 v (pi(z) - pi(y))) / (pi(x) - pi(y))   Eq. (4.7)
//     mira:     z ~ Q2(. | y, x), a2 = 1 ^ pi(z) Q1(y|z) Q2(x|y,z) (1 - a1(z,y))
//                                        / (pi(x) Q1(y|x) Q2(z|y,x) (1 - a1(x,y)))   Eq. (4.2)
//     green:    with the fictional y* = z - (y - x), Eqs. (4.8)-(4.10); for a symmetric Q1 and a symmetric Q2 that
//               ignores y every density cancels:  a2 = 1 ^ (0 v (pi(z) - pi(y*))) / (pi(x) - pi(y)).
// Waste recycling (Sec. 4.2.6): the step reports the expected-value weights of x, y and z:
//   w_y = a1, w_z = (1 - a1) a2, w_x = 1 - w_y - w_z; y* never receives weight.
//
// THE STATE SPACE. A state is an infinite sequence of coordinates (every coordinate exists); the target depends
// on those its path reads, and which coordinates a path reads depends only on the values it has read before
// (a path is a program that reads numbers). Under the target, the coordinates a state's path does not read are
// then independent uniforms, whatever the coordinates it reads. Three rules follow, and make every chain type
// exact (tests/mlt/test_chain.cpp, TransDimensional*):
//   1. Refresh. At the start of each step, the coordinates x's path did not read are forgotten and redrawn
//      uniformly when next needed: a Gibbs update of the unread coordinates given the read ones, which leaves
//      the target invariant because the set it refreshes is a function of x alone. (What x read is kept per
//      coordinate pair, so an unread coordinate that shares a pair with a read one is kept, not refreshed.)
//   2. Lazy, consistent realisation. Within a step, a coordinate pair is realised the first time any proposal
//      needs it: x's pair first (a uniform draw if x's path did not read it; it is then part of x for the rest
//      of the step, shared by every proposal), then y's from x's by Q1, z's from x's (and y's) by Q2, and y*'s
//      as z - (y - x). Drawing a coordinate when it is first needed rather than up front does not change its
//      law, because nothing decided so far depended on it. A path therefore costs only the pairs it reads: the
//      state is as long as the path, not as the longest path the chain ever accepted.
//   3. Only kernels whose densities cancel on unread coordinates. The first stage must be a symmetric random
//      walk (Mutation::symmetric(): every built-in kernel), so that Q1 cancels from a1 on every coordinate,
//      read or not. Orbital needs a pairwise-isotropic first stage (Eq. 4.7 has no densities). Green–Mira needs a
//      symmetric second stage that ignores y (every density then cancels, as above). Tierney–Mira cannot cancel
//      Q1(y|z) / Q1(y|x) on coordinates nobody reads, so its second stage moves only the pairs the rejected
//      proposal y read and keeps x's value on the others: there z = x, the Q1 factors are equal and the Q2 factors
//      identical, and the ratio is computed over the pairs y read. This second stage depends on y only through
//      which pairs y read, which is the same in the reverse move (x -> y -> z against z -> y -> x), so Eq. (4.2)
//      holds as written.
//
// Green–Mira's y* is traced only when needed: with 1 - a1(z, y*) <= 1, a2 <= a2_max = 1 ^ pi(z) / (pi(x) (1 - a1));
// if the step's uniform u2 >= a2_max the second stage is rejected whatever pi(y*) is. When y* is traced the
// recycling weight of z is (1 - a1) a2 / a2_max, which is (1 - a1) a2 in expectation over u2: unbiased.
//
// STREAMS AND FIXED PAIRS (multiplexed MLT, thesis Sec. 4.3.1.2). A technique with several sample streams lays
// its coordinates out pair by pair (render/pss.h: pair p belongs to stream p % streams), so the chain can treat
// streams differently without knowing what they mean:
//   - fixed_pairs: pairs (a bit per pair index, the first 64) that small steps keep at x's value, in both stages
//     and in the mixture: MMLT's strategy selector. Large steps redraw them. The kernel is then the product of the
//     identity on those pairs and the configured kernel on the others: still symmetric, and Eq. (4.7) still holds
//     (Q1(y|z) = Q1(y|x) on pairs where x = y = z).
//   - set_second_stage_streams(mask): the streams the second stage moves; its other pairs keep x's value (MMLT's
//     "fix the emitter subpath, move the sensor subpath"). The mask may change from step to step as a function of
//     the fixed pairs (the strategy), which x and z share, so the reverse move z -> y -> x uses the same mask and
//     Eqs. (4.2), (4.7) and (4.10) hold with the sums and ratios over the moved pairs (on the others z = x).
//   - mixture: instead of two stages, each step proposes with the first stage's kernel or, with probability 1/2,
//     with the second stage's (for the orbital kernel: a first-stage draw y, then z on its orbit through x, never
//     evaluated), accepted by plain Metropolis. Valid when that composite kernel is symmetric: a second stage
//     that ignores y and is symmetric, or orbital after a pairwise-isotropic first stage (z - x is then
//     (I - R(theta)) (y - x), isotropic). The "MMLT / X" baseline of Fig. 4.11.
//
// LOCAL KERNELS (local.h: H2MC). A kernel whose proposal is local (Mutation::local(latent), e.g. `h2mc`, alone or
// as a mixture component) moves every pair x's path read jointly, by a Gaussian built from the gradient and Hessian
// of log pi at x, which the chain asks the target for (set_derivatives). The proposal w's Gaussian is built too,
// for the reverse density, and only when pi(w) > 0; x's is cached while x stays (a rejected step costs no new
// derivatives at x) and w's becomes x's when w is accepted. Allowed as the single stage (type None: MH with the
// Hastings ratio of local.h; large steps as usual) and as Green–Mira's second stage, where (Q1 symmetric, Q2
// ignoring y) Eq. (4.10) becomes
//     a2 = 1 ^ (0 v (pi(z) - pi(y*))) Q2(x | z) / ((pi(x) - pi(y)) Q2(z | x)),
// with the ratio of local.h. A mixture picks its component independently of the state, so each component may be
// accepted with its own ratio (a symmetric one by the usual formulas). Not with Tierney–Mira, orbital, the mixture
// mode, several streams or fixed pairs (refused by check()).
// Adaptive local kernels (local.h: AdaptiveLocalKernel, `langevin`) use the gradient only (the query's hess is null)
// and a per-chain adaptation state that is frozen within a step and updated at its end from the gradient of the
// state the chain is then in (once per state), after which x's Gaussian is rebuilt under the new state.
//
// Invalid target values (NaN, Inf, negative) make a proposal invalid: acceptance 0, counted, never weighted.
// No allocation per step once the state arrays have grown to the longest path.
#include <kelvin/core/coordinates.h>
#include <kelvin/core/random.h>
#include <kelvin/mlt/mutation.h>

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace kelvin {

class LocalKernel;
class BlockGaussian;

/// What a local kernel asks the target for: the gradient and Hessian of log pi at a state with respect to the
/// coordinates of the pairs its path read (the block, in increasing pair order).
struct DerivativeQuery {
    const double* coords = nullptr;  ///< the state's coordinates: index i is coords[i] (read pairs are realised)
    const int* block = nullptr;      ///< per coordinate i < length: its position in the block, -1 if not read
    std::size_t length = 0;          ///< coordinates `block` covers (2 x one past the highest read pair)
    int n = 0;                       ///< block size (2 x the pairs read)
    double value = 0;                ///< pi at the state (positive)
    double* grad = nullptr;          ///< out: d log pi / d block_k, n values, zeroed by the chain
    double* hess = nullptr;          ///< out: n x n column-major, zeroed by the chain; null: gradient only
                                     ///< (adaptive, gradient-based kernels: langevin)
};
/// Fills grad and hess; returns false where log pi is not twice differentiable at the state (a discontinuity,
/// an unsupported plugin): the local kernel then falls back to its isotropic Gaussian (counted).
using TargetDerivatives = std::function<bool(const DerivativeQuery&)>;

enum class DrType { None, Orbital, Mira, Green };
DrType parse_dr_type(const std::string& s);  // "none" | "orbital" | "mira" | "green"
const char* to_string(DrType t);

struct ChainConfig {
    const Mutation* first = nullptr;   ///< stage-1 kernel (required)
    const Mutation* second = nullptr;  ///< stage-2 kernel (required unless type == None)
    DrType type = DrType::None;
    double large_step_prob = 0.0;
    bool timid_after_large = false;  ///< attempt a second stage after a rejected large step
    bool mixture = false;            ///< one stage, the two kernels mixed with equal weights (see above)
    int streams = 1;                 ///< sample streams: pair p belongs to stream p % streams
    uint64_t fixed_pairs = 0;        ///< bit p: small steps keep pair p (p < 64)
};
/// What is wrong with a configuration: the part at fault ("first", "second", "type", "large_step_prob",
/// "mixture", "streams") and why.
struct ChainConfigProblem {
    const char* part;
    std::string why;
};
/// The first problem of `config` (a missing kernel, or a kernel that breaks rule 3 above), if any.
std::optional<ChainConfigProblem> check(const ChainConfig& config);
/// Throws Error with check()'s reason.
void validate(const ChainConfig& config);

/// Which state a target evaluation is for (lets the caller keep per-state data, e.g. splats).
enum class Slot : uint8_t { X = 0, Y = 1, Z = 2, YStar = 3 };

struct StepOutcome {
    int accepted = 0;    ///< 0: stayed at x; 1: moved to y; 2: moved to z
    bool large = false;  ///< the first stage was a large step
    bool second_stage = false;
    bool ystar_traced = false;         ///< Green–Mira evaluated y* (false when u2 decided without it)
    double a1 = 0, a2 = 0;             ///< a2: 0 when a Green–Mira second stage was decided without y*
    double w_x = 1, w_y = 0, w_z = 0;  ///< waste-recycling weights of the old state, y and z
};

struct ChainStats {
    uint64_t steps = 0, large_steps = 0, large_accepted = 0;
    uint64_t stage1_accepted = 0, stage2_attempted = 0, stage2_accepted = 0;
    uint64_t evaluations = 0, invalid = 0;
    uint64_t ystar_evaluations = 0, ystar_skipped = 0;         ///< Green–Mira: y* traced, y* not needed
    uint64_t pairs_realised = 0;                               ///< proposal coordinate pairs drawn (y, z, y*)
    uint64_t mixture_second = 0, mixture_second_accepted = 0;  ///< mixture: steps proposed by the second kernel
    double seconds_stage1 = 0;  ///< first stage: sampling y, evaluating it, deciding (sampled, see below)
    double seconds_stage2 = 0;  ///< second stage: sampling z (and y*), evaluating, densities, deciding
    // Local kernels (h2mc): proposals made by them, derivative evaluations (x's and proposals'), the Gaussians that
    // fell back to isotropic because the target could not differentiate or because the Hessian was small, and
    // (with stage timing, every call timed) the seconds in derivatives and in building the Gaussians.
    uint64_t local_proposals = 0, local_accepted = 0, derivatives = 0, not_differentiable = 0, small_hessian = 0;
    double seconds_derivatives = 0, seconds_gaussians = 0;

    ChainStats& operator+=(const ChainStats& o) {
        steps += o.steps, large_steps += o.large_steps, large_accepted += o.large_accepted;
        stage1_accepted += o.stage1_accepted, stage2_attempted += o.stage2_attempted;
        stage2_accepted += o.stage2_accepted, evaluations += o.evaluations, invalid += o.invalid;
        ystar_evaluations += o.ystar_evaluations, ystar_skipped += o.ystar_skipped;
        pairs_realised += o.pairs_realised;
        mixture_second += o.mixture_second, mixture_second_accepted += o.mixture_second_accepted;
        seconds_stage1 += o.seconds_stage1, seconds_stage2 += o.seconds_stage2;
        local_proposals += o.local_proposals, local_accepted += o.local_accepted, derivatives += o.derivatives;
        not_differentiable += o.not_differentiable, small_hessian += o.small_hessian;
        seconds_derivatives += o.seconds_derivatives, seconds_gaussians += o.seconds_gaussians;
        return *this;
    }
};

class MarkovChain {
public:
    /// Evaluates the target on the state `source` reads (slot says which). Returns pi >= 0.
    using Target = std::function<double(CoordinateSource& source, Slot slot)>;

    /// `stage_timing`: measure stage times on every 16th step (two clock reads per stage), for
    /// ChainStats::seconds_stage*; scaled by 16 to estimate the whole run's.
    MarkovChain(const ChainConfig& config, uint64_t seed, uint64_t stream, bool stage_timing = false);
    ~MarkovChain();
    MarkovChain(const MarkovChain&) = delete;  // its sources point at it
    MarkovChain& operator=(const MarkovChain&) = delete;

    /// The target's derivatives, required before the first step when a kernel has local proposals (h2mc).
    void set_derivatives(TargetDerivatives derivatives);

    /// Starts the chain at x0 (its path reads the coordinates it needs; missing ones are drawn uniformly) and
    /// returns pi(x0). Throws Error if pi(x0) is not positive and finite.
    double start(const Target& target, const std::vector<double>& x0);

    /// Adaptive local kernels (local.h, AdaptiveLocalKernel: langevin): runs `steps` steps from `independent`, a state
    /// drawn independently of the x0 the chain will be started at, adapting the chain's adaptation state, then freezes
    /// that state and clears the statistics; start() must follow. The chain's kernel is then fixed and independent of
    /// its start, so the run is exact (an adaptation learnt from the chain's own run is not: local.h).
    void warm_up(const Target& target, const std::vector<double>& independent, int steps);
    /// Clears the statistics (stats()).
    void reset_stats() { m_stats = ChainStats{}; }

    /// One DR step. Before the call, state()/value() are x; after it, the new current state. previous(), y()
    /// and z() hold the step's states (x and its proposals) for waste recycling, until the next step; only the
    /// coordinate pairs realised during the step are meaningful (those the states' paths read among them).
    StepOutcome step(const Target& target);

    const std::vector<double>& state() const { return m_s[0].v; }
    double value() const { return m_pi[0]; }
    const std::vector<double>& previous() const { return m_s[m_last.accepted].v; }
    double value_previous() const { return m_pi[m_last.accepted]; }
    const std::vector<double>& y() const { return m_s[m_last.accepted == 1 ? 0 : 1].v; }
    const std::vector<double>& z() const { return m_s[m_last.accepted == 2 ? 0 : 2].v; }
    double value_y() const { return m_pi[m_last.accepted == 1 ? 0 : 1]; }
    double value_z() const { return m_pi[m_last.accepted == 2 ? 0 : 2]; }
    /// The streams (bit s: pairs p with p % streams == s) the next second stages (or mixture components) move;
    /// the others keep x's value. All streams by default.
    void set_second_stage_streams(uint32_t mask) { m_second_streams = mask; }
    /// During a step of a mixture chain: the proposal y comes from the second kernel.
    bool proposing_with_second() const { return m_mix_second; }
    /// Coordinates (pairs x 2) the current state's path read.
    std::size_t state_length() const;
    const ChainStats& stats() const { return m_stats; }
    Random& rng() { return m_rng; }

private:
    struct Lazy {
        std::vector<double> v;           ///< coordinate values, two per pair
        std::vector<uint32_t> realised;  ///< per pair: the step (epoch) in which it was realised
        std::vector<uint32_t> read;      ///< per pair: the epoch in which this state's own evaluation read it
    };
    /// The CoordinateSource a target reads a slot through.
    struct Source final : CoordinateSource {
        MarkovChain* chain = nullptr;
        int slot = 0;
        double at(std::size_t i) override { return chain->coordinate(slot, i); }
    };

    double coordinate(int slot, std::size_t i);
    void ensure(int slot, std::size_t pair);
    void grow(std::size_t pairs);
    bool x_valid(std::size_t pair) const { return m_s[0].read[pair] == m_x_epoch || m_s[0].realised[pair] == m_epoch; }
    double evaluate(const Target& target, int slot);
    bool fixed_small(std::size_t p) const { return p < 64 && ((m_cfg.fixed_pairs >> p) & 1); }
    bool moved_second(std::size_t p) const { return (m_second_streams >> (p % std::size_t(m_cfg.streams))) & 1; }
    void next_epoch();
    double tierney_mira_log_ratio(double a1);
    struct LocalState;
    bool local_gaussian(int slot, const LocalKernel& k);
    void sample_local_block(int slot);
    double local_log_ratio(int slot, const LocalKernel& k);

    ChainConfig m_cfg;
    Random m_rng;
    bool m_timing;
    std::array<Lazy, 4> m_s;  // x, y, z, y*
    std::array<Source, 4> m_src;
    std::array<double, 4> m_pi{0, 0, 0, 0};
    std::vector<double> m_scratch;  // Tierney–Mira: the pairs y read, gathered
    std::size_t m_pairs = 0;        // capacity in pairs of every Lazy
    std::size_t m_y_read_end = 0;   // one past the highest pair y's path read (this step)
    uint32_t m_epoch = 1, m_x_epoch = 1;
    uint64_t m_latent1 = 0, m_latent2 = 0;
    uint32_t m_second_streams = ~0u;
    bool m_large = false, m_started = false, m_mix_second = false;
    StepOutcome m_last;
    ChainStats m_stats;
    std::unique_ptr<LocalState> m_local;  // local kernels: derivatives, Gaussians of x and of the proposal
    TargetDerivatives m_derivatives;
    const LocalKernel* m_local_accepted_kernel = nullptr;  // the local kernel that made an accepted z
};

}  // namespace kelvin
