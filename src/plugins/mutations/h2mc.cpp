// h2mc: the anisotropic Gaussian mutation of Hessian-Hamiltonian Monte Carlo (Li et al. 2015, "Anisotropic
// Gaussian mutations for Metropolis light transport through Hessian-Hamiltonian dynamics"), with the parameters
// the thesis' authors ran it with (sigma 0.01, L = pi/2; Sec. 4.3.2). A local kernel (include/kelvin/mlt/local.h):
// every coordinate pair the current state's path read moves jointly by N(mu_x, Sigma_x), built from the gradient and
// Hessian of log pi at x (Eigen's SelfAdjointEigenSolver; the formulas are at h2mc_gaussian in src/mlt/local.cpp),
// falling back to the isotropic N(0, sigma^2 I) where the Hessian's Frobenius norm is below 0.5 / sigma^2 or the
// target cannot differentiate; the pairs it did not read move by a truncated N(0, sigma^2) each (the outside law).
// The chain asks the target for the derivatives and computes the Hastings ratio (chain.h, "local kernels").
//
// Use it as the single stage (`pssmlt`: the H2MC baseline) or as the second stage of `drmlt` type `green`; the
// thesis' cheap-then-expensive hybrid is a Gaussian first stage (sigma 0.01) and, as the second, an equally weighted
// `mixture` of `h2mc` and a `gaussian` of sigma 0.0025. The target must provide derivatives: the Metropolis
// integrators take them from the path technique's differentiable evaluation (mlt/path_derivatives.h) and refuse
// h2mc with the other techniques.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <mutation type="mixture">
//         <mutation type="h2mc"/>
//         <mutation type="gaussian"><float name="sigma" value="0.0025"/></mutation>
//     </mutation>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/local.h>
#include <kelvin/mlt/mutation.h>

namespace kelvin {
namespace {

class H2mc final : public Mutation, public LocalKernel {
public:
    explicit H2mc(const Properties& props) {
        m_params.sigma = props.get_float("sigma", 1e-6, 1.0 / 32);
        m_params.L = props.get_float("L", 1e-3, 3.0);
    }
    // Pairs outside the block (and any pairwise use): the outside law.
    void sample_pair(uint64_t, const double* x, double* y, Random& rng) const override {
        sample_outside_pair(m_params.sigma, x, y, rng);
    }
    double log_density(Coords from, Coords to) const override {
        double lp = 0;
        for (std::size_t i = 0; i + 1 < from.size(); i += 2)
            lp += outside_log_pdf(m_params.sigma, torus_delta(from[i], to[i]), torus_delta(from[i + 1], to[i + 1]));
        return lp;
    }
    double scale() const override { return m_params.sigma; }
    const LocalKernel* local(uint64_t) const override { return this; }
    bool has_local() const override { return true; }

    LocalBuild build(int n, const double* grad, const double* hess, bool differentiable, LocalWorkspace& ws,
                     BlockGaussian& out) const override {
        if (!differentiable) {
            out.set_isotropic(n, m_params.sigma);
            return LocalBuild::NotDifferentiable;
        }
        return h2mc_gaussian(m_params, n, grad, hess, ws, out);
    }
    double outside_sigma() const override { return m_params.sigma; }

private:
    H2mcParameters m_params;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::H2mc, "mutation", "h2mc",
              "Hessian-Hamiltonian anisotropic Gaussian (Li et al. 2015); needs the target's derivatives.",
              kelvin::param::real("sigma", 0.01, "isotropic scale (prior, fallback, outside law)"),
              kelvin::param::real("L", 1.5707963267948966, "Hamiltonian phase per eigendirection"));
