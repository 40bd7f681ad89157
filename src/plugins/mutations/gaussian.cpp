// gaussian: independent wrapped-normal perturbation of every coordinate, N(0, sigma^2) per coordinate
// (the PSSMLT/G baseline), two normals per pair by Marsaglia's polar method. The density sums the nearest periodic
// images (|k| <= 2), exact to double precision for sigma <= 1/8.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <mutation type="gaussian"><float name="sigma" value="0.01"/></mutation>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/mutation.h>

namespace kelvin {
namespace {

class Gaussian final : public Mutation {
public:
    explicit Gaussian(const Properties& props) : m_sigma(props.get_float("sigma", 1e-9, 0.125)) {
        m_log_norm = -std::log(m_sigma * std::sqrt(2 * Pi));
    }
    void sample_pair(uint64_t, const double* x, double* y, Random& rng) const override {
        const Vec2d g = standard_normal2_polar(rng);
        y[0] = torus_wrap(x[0] + m_sigma * g.x);
        y[1] = torus_wrap(x[1] + m_sigma * g.y);
    }
    double log_density(Coords from, Coords to) const override {
        // Per coordinate: log(norm * sum_k exp(-(d + k)^2 / (2 sigma^2))), factored around the nearest image
        // (d itself, |d| <= 1/2) so that no term underflows to a zero density however small sigma is.
        double lp = 0;
        for (std::size_t i = 0; i < from.size(); ++i) {
            const double d = torus_delta(from[i], to[i]), e0 = d / m_sigma;
            double s = 0;
            for (int k = -2; k <= 2; ++k) {
                const double e = (d + k) / m_sigma;
                s += std::exp(-0.5 * (e * e - e0 * e0));  // k = 0 gives 1; the others are <= 1
            }
            lp += m_log_norm - 0.5 * e0 * e0 + std::log(s);
        }
        return lp;
    }
    double scale() const override { return m_sigma; }
    bool pairwise_isotropic() const override { return true; }

private:
    double m_sigma, m_log_norm;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Gaussian, "mutation", "gaussian", "Wrapped-normal perturbation of every coordinate.",
              kelvin::param::real("sigma", 1.0 / 64, "standard deviation"));
