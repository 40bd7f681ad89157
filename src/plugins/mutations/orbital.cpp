// orbital: the pairwise orbital second stage of delayed rejection (thesis Sec. 4.2.4, Algorithm B.2 stage 2).
// For each coordinate pair, z moves on the circle centred on the rejected proposal y through the current state
// x, at an angle theta from x drawn from the wrapped Cauchy distribution, Eq. (4.6):
//     Q(theta; rho) = (1 - rho^2) / (2 pi (1 + rho^2 - 2 rho cos theta)),
// sampled by inverting its CDF: theta = 2 atan(((1 - rho) / (1 + rho)) tan(pi (u - 1/2))).
// Then Q1(y|z) = Q1(y|x) for a circularly symmetric first stage and the acceptance reduces to Eq. (4.7).
// Differences use the minimum image on the torus. An odd last coordinate keeps x's value (its 1D "orbit"
// {x, 2y - x} is left alone, which keeps the kernel symmetric).
// Only valid as the second stage of drmlt with type="orbital" after a circularly symmetric first stage
// (kelemen_pair, or a large step).
//
// | parameter | type  | default     | meaning                                     |
// |-----------|-------|-------------|---------------------------------------------|
// | rho       | float | exp(-1/4)   | wrapped-Cauchy concentration, in (0, 1)     |
//
//     <mutation type="orbital" name="second"/>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/mutation.h>

namespace kelvin {
namespace {

class Orbital final : public Mutation {
public:
    explicit Orbital(const Properties& props) : m_rho(props.get_float("rho", 1e-9, 1 - 1e-9)) {
        m_tan_scale = (1 - m_rho) / (1 + m_rho);
    }
    bool second_stage_only() const override { return true; }
    void sample(Coords x, std::span<double> y, Random&) const override {
        for (std::size_t i = 0; i < x.size(); ++i) y[i] = x[i];  // never used as a first stage
    }
    double log_density(Coords, Coords) const override { return -Inf; }  // singular (on an orbit)

    void sample_second(Coords x, Coords y, std::span<double> z, Random& rng) const override {
        const std::size_t n = x.size();
        std::size_t i = 0;
        for (; i + 1 < n; i += 2) {
            // u = y - x (minimum image); the orbit is centred on y and passes through x.
            double u1 = torus_delta(x[i], y[i]), u2 = torus_delta(x[i + 1], y[i + 1]);
            double r = std::sqrt(u1 * u1 + u2 * u2);
            if (!(r > 0)) {
                z[i] = x[i];
                z[i + 1] = x[i + 1];
                continue;
            }
            double mu = std::atan2(-u2, -u1);  // direction of x - y
            double mu2 = mu + sample_angle(rng.next_double());
            z[i] = torus_wrap(x[i] + u1 + r * std::cos(mu2));  // y + r (cos mu', sin mu'), y = x + u
            z[i + 1] = torus_wrap(x[i + 1] + u2 + r * std::sin(mu2));
        }
        if (i < n) z[i] = x[i];
    }
    double log_density_second(Coords, Coords, Coords) const override { return -Inf; }

    /// Wrapped-Cauchy angle in (-pi, pi].
    double sample_angle(double u) const { return 2 * std::atan(m_tan_scale * std::tan(Pi * (u - 0.5))); }
    double angle_pdf(double theta) const {
        return (1 - m_rho * m_rho) / (2 * Pi * (1 + m_rho * m_rho - 2 * m_rho * std::cos(theta)));
    }

private:
    double m_rho, m_tan_scale;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Orbital, "mutation", "orbital",
              "Pairwise orbital second stage (wrapped Cauchy on the orbit of y through x, Sec. 4.2.4).",
              kelvin::param::real("rho", 0.7788007830714049, "wrapped-Cauchy concentration exp(-1/4)"));
