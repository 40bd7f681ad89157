// langevin: preconditioned Metropolis-adjusted Langevin (MALA) proposals in primary sample space, after Luan, Zhao,
// Bala and Gkioulekas 2020, "Langevin Monte Carlo Rendering with Gradient-based Adaptation" (ACM TOG 39(4)). A local
// kernel (include/kelvin/mlt/local.h): the pairs x's path read (the block, n coordinates) move jointly by
//     x' = x + (eps^2 / 2) M g(x) + eps M^(1/2) z,   z ~ N(0, I_n),   g = grad log pi,
// with eps = `sigma` and a diagonal preconditioner M = diag(m_i), m_i = delta / (delta + sqrt(v_i)), where v_i is the
// chain's running second moment of the gradient in primary-sample coordinate i (RMSprop's / Adam's denominator,
// normalised so that m_i <= 1: a coordinate whose log-gradient is small against `delta` takes the full step eps, one
// whose gradient is large a step shrunk as 1 / sqrt(|g|)). The pairs x's path did not read move by the outside law
// N(0, eps^2 I_2), as for h2mc.
//
// THE METROPOLIS-HASTINGS RATIO. The proposal is the Gaussian N(mu_x, Sigma) with mu_x = (eps^2 / 2) M g(x) and
// Sigma = eps^2 M; the chain's local ratio (local.h, MarkovChain::local_log_ratio) accepts x -> y with
//     a = 1 ^ pi(y) N(x - y; mu_y, Sigma) / (pi(x) N(y - x; mu_x, Sigma))   (times the outside law's terms),
// where mu_y uses the gradient at y and the same M: the reverse move's density is the kernel's at y, under the
// adaptation state the step was made with (with preconditioner="local", M(y) and Sigma(y) = eps^2 M(y) from y's
// gradient). As the second stage of Green–Mira DR (after a cheap first stage, e.g. a
// Gaussian) the same ratio Q2(x | z) / Q2(z | x) enters Eq. (4.10).
//
// ADAPTATION AND THE STATIONARY DISTRIBUTION (`preconditioner`, `warmup`). M is the only adapted quantity (no
// momentum).
//   - `adaptive` (default): v_i is the chain's running second moment of g_i. The paper adapts online and appeals to
//     controlled-MCMC theory (diminishing adaptation, Roberts & Rosenthal 2007) for ergodicity. Kelvin's kernel:
//       1. is frozen within a step (its proposal and, in DR, its second stage): the forward and the reverse densities
//          are built under the same M, so every step's kernel satisfies detailed balance for pi;
//       2. changes between steps, once per state the chain enters, from that state's gradient: v_i is the plain
//          running mean of g_i^2 (weight 1/k for the k-th observation of coordinate i: Adam's bias-corrected second
//          moment with beta2 -> 1), so the adaptation diminishes, and it stops after `adapt_steps` observations;
//       3. with `warmup` > 0 (default 32) learns only on a warm-up: the integrator runs each chain `warmup` steps from
//          its own independent draw of the bootstrap states, freezes M (MarkovChain::warm_up) and starts the chain at
//          its start state. M is then independent of the start, which is distributed as pi (up to the bootstrap, as
//          for every kernel), and the kernel is fixed: the run is exact. Nothing of the warm-up is splatted.
//     With `warmup` = 0 the chain adapts online during the run, as the paper does: M is learnt from the chain's own
//     states, state and M are dependent, and a chain started in the stationary distribution leaves it while it
//     adapts and returns at its mixing rate once M freezes: a start-up transient, asymptotically zero, measurable in
//     short runs (docs/mlt.md gives its size).
//   - `local`: m_i = delta / (delta + |g_i(x)|), the gradient at the state itself (RMSprop with beta2 = 0). A
//     function of the state alone, so the reverse density uses M(y) and g(y) and the chain is exact in every step.
//   - `none`: M = I, plain MALA (exact).
// Each chain owns its state (MarkovChain's LocalState), so images stay identical whatever the thread count.
//
// THE BOUNDARY. Primary sample space is the unit torus: steps are minimum-image differences, states wrap, and the
// Gaussian is truncated to the box (-1/2, 1/2)^n (local.h). The drift is truncated as in MALTA (Roberts & Tweedie
// 1996): scaled down, as a vector, so that no coordinate of it exceeds `max_drift` of that coordinate's standard
// deviation (a deterministic function of x, so the ratio stays exact); with eps <= 1/32 and max_drift <= 8 every mean
// is within 1/4 and the truncated mass is negligible (local.h). Where the target cannot differentiate (a path outside
// the differentiable set, next to a discontinuity, a mismatch: PathDerivativeStatus not Ok) or the gradient is not
// finite, the block moves by N(0, eps^2 I) (counted as not differentiable), as h2mc falls back.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <mutation type="langevin"><float name="sigma" value="0.01"/></mutation>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/local.h>
#include <kelvin/mlt/mutation.h>

#include <algorithm>
#include <cmath>

namespace kelvin {
namespace {

class Langevin final : public Mutation, public AdaptiveLocalKernel {
public:
    explicit Langevin(const Properties& props) {
        m_sigma = props.get_float("sigma", 1e-6, 1.0 / 32);
        m_delta = props.get_float("delta", 1e-9, 1e12);
        m_adapt_steps = uint32_t(props.get_int("adapt_steps", 0, 1000000000));
        const std::string pre = props.get_string("preconditioner");
        if (pre == "adaptive")
            m_mode = Mode::Adaptive;
        else if (pre == "local")
            m_mode = Mode::Local;
        else if (pre == "none")
            m_mode = Mode::None;
        else
            props.error("preconditioner", "'" + pre + "' is not one of adaptive, local, none");
        m_warmup = int(props.get_int("warmup", 0, 1000000));
        if (m_mode != Mode::Adaptive) m_adapt_steps = 0, m_warmup = 0;
        m_max_drift = props.get_float("max_drift", 0.0, 8.0);
    }

    // Pairs outside the block: the outside law.
    void sample_pair(uint64_t, const double* x, double* y, Random& rng) const override {
        sample_outside_pair(m_sigma, x, y, rng);
    }
    double log_density(Coords from, Coords to) const override {
        double lp = 0;
        for (std::size_t i = 0; i + 1 < from.size(); i += 2)
            lp += outside_log_pdf(m_sigma, torus_delta(from[i], to[i]), torus_delta(from[i + 1], to[i + 1]));
        return lp;
    }
    double scale() const override { return m_sigma; }
    const LocalKernel* local(uint64_t) const override { return this; }
    bool has_local() const override { return true; }
    double outside_sigma() const override { return m_sigma; }

    /// Without a chain's state: M = I (plain MALA).
    LocalBuild build(int n, const double* grad, const double*, bool differentiable, LocalWorkspace&,
                     BlockGaussian& out) const override {
        static const LocalAdaptation none;
        return build_adapted(none, n, nullptr, grad, differentiable, out);
    }

    LocalBuild build_adapted(const LocalAdaptation& state, int n, const uint32_t* pairs, const double* grad,
                             bool differentiable, BlockGaussian& out) const override {
        bool finite = differentiable;
        for (int i = 0; i < n && finite; ++i) finite = std::isfinite(grad[i]);
        if (!finite) {
            out.set_isotropic(n, m_sigma);
            return LocalBuild::NotDifferentiable;
        }
        out.resize(n);
        double* mean = out.mean();
        double* sd = out.sd();
        double* basis = out.basis();
        double worst = 0;  // the largest |drift| / sd over the block
        for (int i = 0; i < n; ++i) {
            const double m =
                m_mode == Mode::Local ? m_delta / (m_delta + std::abs(grad[i])) : preconditioner(state, pairs, i);
            sd[i] = m_sigma * std::sqrt(m);
            mean[i] = 0.5 * m_sigma * m_sigma * m * grad[i];
            worst = std::max(worst, std::abs(mean[i]) / sd[i]);
        }
        if (worst > m_max_drift) {  // MALTA: the drift scaled down as a vector
            const double f = m_max_drift / worst;
            for (int i = 0; i < n; ++i) mean[i] *= f;
        }
        const std::size_t un = std::size_t(n);
        std::fill(basis, basis + un * un, 0.0);
        for (std::size_t i = 0; i < un; ++i) basis[i * un + i] = 1;
        out.finish();
        return LocalBuild::Anisotropic;
    }

    void adapt(LocalAdaptation& state, int n, const uint32_t* pairs, const double* grad,
               bool differentiable) const override {
        if (state.frozen || !differentiable || m_adapt_steps == 0 || !pairs || n < 2) return;
        for (int i = 0; i < n; ++i)
            if (!std::isfinite(grad[i])) return;
        const std::size_t need = 2 * (std::size_t(pairs[n / 2 - 1]) + 1);
        if (state.moment.size() < need) {
            state.moment.resize(need, 0.0);
            state.count.resize(need, 0);
        }
        for (int i = 0; i < n; ++i) {
            const std::size_t c = coordinate(pairs, i);
            if (state.count[c] >= m_adapt_steps) continue;  // frozen
            const uint32_t k = ++state.count[c];
            state.moment[c] += (grad[i] * grad[i] - state.moment[c]) / double(k);
        }
        ++state.updates;
    }

    int warmup_steps() const override { return m_warmup; }

private:
    static std::size_t coordinate(const uint32_t* pairs, int i) {
        return 2 * std::size_t(pairs[i / 2]) + std::size_t(i % 2);
    }
    /// m_i of block entry i: 1 before the coordinate's first observation.
    double preconditioner(const LocalAdaptation& state, const uint32_t* pairs, int i) const {
        if (!pairs) return 1;
        const std::size_t c = coordinate(pairs, i);
        if (c >= state.count.size() || state.count[c] == 0) return 1;
        return m_delta / (m_delta + std::sqrt(state.moment[c]));
    }

    enum class Mode { Adaptive, Local, None };
    Mode m_mode = Mode::Adaptive;
    double m_sigma = 0.01, m_delta = 100, m_max_drift = 2;
    uint32_t m_adapt_steps = 1000;
    int m_warmup = 32;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::Langevin, "mutation", "langevin",
    "Preconditioned Metropolis-adjusted Langevin (Luan et al. 2020); needs the target's gradient.",
    kelvin::param::real("sigma", 0.01, "step eps: standard deviation where unpreconditioned (<= 1/32)"),
    kelvin::param::real("delta", 100.0, "gradient scale of the preconditioner delta / (delta + sqrt(v))"),
    kelvin::param::string("preconditioner", "adaptive",
                          "adaptive (the chain's running moments), local (the state's gradient), none (M = I)"),
    kelvin::param::integer("adapt_steps", 1000, "observations per coordinate before M freezes; 0: M = I"),
    kelvin::param::integer("warmup", 32,
                           "adaptive: steps per chain from an independent start, then M frozen; 0: online"),
    kelvin::param::real("max_drift", 2.0, "drift cap in standard deviations per coordinate, at most 8 (MALTA)"));
