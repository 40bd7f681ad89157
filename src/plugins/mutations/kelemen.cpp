// kelemen: Kelemen et al.'s (2002) per-coordinate exponential perturbation, thesis Eq. (4.5):
//     y_i = x_i + sgn(xi_1 - 1/2) eps_max exp(-log(eps_max / eps_min) xi_2),
// so |y_i - x_i| lies in [eps_min, eps_max] with density 1 / (|d| log(eps_max/eps_min)), symmetric in sign.
// Symmetric; note the hole around zero, which is why Tierney–Mira DR after it can suffer vanishing acceptance.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <mutation type="kelemen"><float name="eps_max" value="0.03125"/></mutation>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/mutation.h>

namespace kelvin {
namespace {

class Kelemen final : public Mutation {
public:
    explicit Kelemen(const Properties& props) : m_law(KelemenLaw::from(props)) {}
    void sample_pair(uint64_t, const double* x, double* y, Random& rng) const override {
        y[0] = torus_wrap(x[0] + m_law.sample_signed(rng));
        y[1] = torus_wrap(x[1] + m_law.sample_signed(rng));
    }
    double log_density(Coords from, Coords to) const override {
        double lp = 0;
        for (std::size_t i = 0; i < from.size() && lp > -Inf; ++i)
            lp += m_law.signed_log_pdf(torus_delta(from[i], to[i]));
        return lp;
    }
    double scale() const override { return m_law.eps_max; }

private:
    KelemenLaw m_law;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Kelemen, "mutation", "kelemen", "Kelemen's per-coordinate exponential perturbation (Eq. 4.5).",
              kelvin::param::real("eps_min", 1.0 / 1024, "smallest step"),
              kelvin::param::real("eps_max", 1.0 / 64, "largest step"));
