// gaussian: independent wrapped-normal perturbation of every coordinate, N(0, sigma^2) per coordinate
// (the PSSMLT/G baseline). The density sums the nearest periodic images (|k| <= 2), exact to double precision
// for sigma <= 1/8.
//
// | parameter | type  | default | meaning                       |
// |-----------|-------|---------|-------------------------------|
// | sigma     | float | 1/64    | standard deviation (<= 1/8)   |
//
//     <mutation type="gaussian"><float name="sigma" value="0.01"/></mutation>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/mutation.h>

namespace kelvin {
namespace {

class Gaussian final : public Mutation {
public:
    explicit Gaussian(const Properties& props) : m_sigma(props.get_float("sigma", 1e-9, 0.125)) {
        m_norm = 1.0 / (m_sigma * std::sqrt(2 * Pi));
    }
    void sample(Coords x, std::span<double> y, Random& rng) const override {
        for (std::size_t i = 0; i < x.size(); i += 2) {
            const Vec2d g = standard_normal2(rng);
            y[i] = torus_wrap(x[i] + m_sigma * g.x);
            if (i + 1 < x.size()) y[i + 1] = torus_wrap(x[i + 1] + m_sigma * g.y);
        }
    }
    double density(Coords from, Coords to) const override {
        double p = 1;
        for (std::size_t i = 0; i < from.size(); ++i) {
            double d = torus_delta(from[i], to[i]), s = 0;
            for (int k = -2; k <= 2; ++k) {
                double e = (d + k) / m_sigma;
                s += std::exp(-0.5 * e * e);
            }
            p *= m_norm * s;
        }
        return p;
    }

private:
    double m_sigma, m_norm;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Gaussian, "mutation", "gaussian", "Wrapped-normal perturbation of every coordinate.",
              kelvin::param::real("sigma", 1.0 / 64, "standard deviation"));
