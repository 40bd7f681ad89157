#pragma once
// Local kernels: proposals shaped by derivatives of the target at the current state, which move every coordinate
// pair the state's path read *jointly* (a correlated Gaussian over that block) instead of pair by pair. The H2MC
// mutation of Li et al. 2015 ("Anisotropic Gaussian mutations for Metropolis light transport through
// Hessian-Hamiltonian dynamics", ACM TOG 34(6)) is one; the chain (chain.h) drives them.
//
// THE KERNEL. Let A be the pairs x's path read (the block, n = 2 |A| coordinates) and delta the minimum-image
// step. A local kernel proposes
//     delta_A ~ N(mu_x, Sigma_x), truncated to the box (-1/2, 1/2)^n (redrawn while outside),
//     delta_p ~ N(0, s^2 I_2) truncated the same way, independently for every pair p outside A (the "outside law"),
// where (mu_x, Sigma_x) depend on the derivatives of log pi at x (a function of x's read coordinates only). Every
// local kernel bounds Sigma_x <= s_max^2 I (s_max <= 1/32) and |mu_x,i| <= 1/4, so the truncated mass is below
// 1e-15 per coordinate (8 standard deviations from the box's faces) and the density is the Gaussian's, to double
// precision. The Hastings ratio of a move x -> w (w read the pairs B) is then, with everything else cancelling
// (the outside law is symmetric, and the same on pairs nobody read):
//     Q(x | w) / Q(w | x) = N_w(x - w over B) prod_{p in A \ B} q_out(x_p - w_p)
//                         / (N_x(w - x over A) prod_{p in B \ A} q_out(w_p - x_p)).
// The chain computes it (MarkovChain, "local kernels"); the Gaussian of x is cached while x stays.
//
// No Eigen in this header: the Gaussian is stored in plain arrays; the eigendecomposition lives in local.cpp.
#include <kelvin/core/random.h>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace kelvin {

/// A Gaussian N(mean, V diag(sd^2) V^T) over a block of n coordinates (V orthonormal, column-major). Storage
/// grows to the largest block seen and is then reused: building and using it allocates nothing once warm.
class BlockGaussian {
public:
    int size() const { return m_n; }
    bool isotropic() const { return m_iso; }
    /// N(0, sigma^2 I_n).
    void set_isotropic(int n, double sigma);
    /// Storage for an n-dimensional Gaussian (contents unspecified until set_from_basis).
    void resize(int n);
    double* mean() { return m_mean.data(); }
    double* basis() { return m_basis.data(); }  ///< n x n, column-major: column k is eigenvector k
    double* sd() { return m_sd.data(); }
    const double* mean() const { return m_mean.data(); }
    const double* basis() const { return m_basis.data(); }
    const double* sd() const { return m_sd.data(); }
    /// After filling mean, basis and sd: computes the normalisation.
    void finish();
    /// A draw of delta (n values), truncated to (-1/2, 1/2)^n.
    void sample(Random& rng, double* delta) const;
    /// log N(delta; mean, Sigma).
    double log_pdf(const double* delta) const;

private:
    int m_n = 0;
    bool m_iso = true;
    double m_iso_sigma = 0, m_log_norm = 0;
    std::vector<double> m_mean, m_basis, m_sd;
    mutable std::vector<double> m_work;  // n: the whitened step
};

/// One draw of N(0, 1) (polar method; the second normal of the pair is discarded).
double standard_normal(Random& rng);

/// The outside law: a coordinate pair's step N(0, sigma^2 I_2) truncated to (-1/2, 1/2)^2.
void sample_outside_pair(double sigma, const double* from, double* to, Random& rng);
/// log density of the outside law for a pair's minimum-image step (dx, dy).
double outside_log_pdf(double sigma, double dx, double dy);

/// Scratch space of the eigendecomposition (Eigen's SelfAdjointEigenSolver, one per block size met): a chain owns
/// one, so that shared kernels stay const and the hot loop does not allocate once warm.
class LocalWorkspace {
public:
    LocalWorkspace();
    ~LocalWorkspace();
    LocalWorkspace(const LocalWorkspace&) = delete;
    LocalWorkspace& operator=(const LocalWorkspace&) = delete;
    struct Impl;
    Impl& impl() { return *m_impl; }

private:
    std::unique_ptr<Impl> m_impl;
};

/// How a local kernel's Gaussian was built.
enum class LocalBuild { Anisotropic, SmallHessian, NotDifferentiable };

/// What a local kernel is to the chain (Mutation::local()).
class LocalKernel {
public:
    virtual ~LocalKernel() = default;
    /// The Gaussian of the block at a state from grad and Hessian of log pi (n values, n x n column-major);
    /// differentiable = false: the target could not differentiate there (the kernel's fallback). Must depend on
    /// its arguments only (the density of the reverse move is rebuilt from the same derivatives).
    virtual LocalBuild build(int n, const double* grad, const double* hess, bool differentiable, LocalWorkspace& ws,
                             BlockGaussian& out) const = 0;
    /// The scale of the outside law.
    virtual double outside_sigma() const = 0;
};

/// Per-chain state of an adaptive local kernel (AdaptiveLocalKernel): running estimates per primary-sample coordinate
/// (index 2 p + j of pair p), grown to the longest path read. The chain owns one; the kernel says what the numbers
/// mean (langevin: the running mean of the squared gradient of log pi, the preconditioner's second moment).
struct LocalAdaptation {
    std::vector<double> moment;   ///< per coordinate: the kernel's running estimate
    std::vector<uint32_t> count;  ///< per coordinate: the observations folded into it
    uint64_t updates = 0;         ///< states folded in
    bool frozen = false;          ///< set by MarkovChain::warm_up: adapt() must not change the state any more
};

/// A local kernel whose Gaussian is built from the gradient of log pi alone (no Hessian: the chain's DerivativeQuery
/// then has hess null) and a per-chain adaptation state, and may depend on which coordinates the block holds
/// (langevin's diagonal preconditioner). The chain finds it by dynamic_cast, so LocalKernel itself is unchanged.
/// The contract that keeps the chain correct (chain.h, "local kernels"):
///   - within a step the state is frozen: the forward density (x's Gaussian) and the reverse one (the proposal's)
///     are built under the same state, so each step's kernel satisfies detailed balance with respect to pi;
///   - between steps the chain folds the gradient of the state it is in (once per visited state whose derivatives
///     were evaluated) into the state by adapt(), then rebuilds x's Gaussian under the new state from the gradient
///     it kept. The kernel's adapt() decides how the adaptation diminishes (langevin.cpp: running means that stop).
/// LocalKernel::build (no state, no coordinates) must be the kernel under an empty LocalAdaptation.
class AdaptiveLocalKernel : public LocalKernel {
public:
    /// The Gaussian of the block under `state`: pairs[q] is the pair index of block entries 2q and 2q + 1, grad and
    /// differentiable as for build(). Must depend on its arguments only.
    virtual LocalBuild build_adapted(const LocalAdaptation& state, int n, const uint32_t* pairs, const double* grad,
                                     bool differentiable, BlockGaussian& out) const = 0;
    /// Folds the gradient of a state the chain is in into `state` (between steps; arguments as for build_adapted).
    virtual void adapt(LocalAdaptation& state, int n, const uint32_t* pairs, const double* grad,
                       bool differentiable) const = 0;
    /// Steps of MarkovChain::warm_up a chain should run from an independent start before its own start, learning the
    /// state and then freezing it (0: adapt online, within the run).
    virtual int warmup_steps() const { return 0; }
};

/// Li et al.'s H2MC Gaussian (see h2mc_gaussian in local.cpp for the formulas).
struct H2mcParameters {
    double sigma = 0.01;            ///< isotropic scale: the prior, the fallback and the outside law
    double L = 1.5707963267948966;  ///< integration "time" per eigendirection
};
/// Builds the H2MC Gaussian from grad and Hessian of log pi; returns SmallHessian (and the isotropic
/// N(0, sigma^2 I)) when the Hessian's Frobenius norm is below 0.5 / sigma^2, as Li et al.'s implementation does.
LocalBuild h2mc_gaussian(const H2mcParameters& p, int n, const double* grad, const double* hess, LocalWorkspace& ws,
                         BlockGaussian& out);

}  // namespace kelvin
