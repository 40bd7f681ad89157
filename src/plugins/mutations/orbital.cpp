// orbital: the pairwise orbital second stage of delayed rejection (thesis Sec. 4.2.4, Algorithm B.2 stage 2).
// For each coordinate pair, z moves on the circle centred on the rejected proposal y through the current state
// x, at an angle theta from x drawn from the wrapped Cauchy distribution, Eq. (4.6):
//     Q(theta; rho) = (1 - rho^2) / (2 pi (1 + rho^2 - 2 rho cos theta)).
// Then Q1(y|z) = Q1(y|x) for a circularly symmetric first stage and the acceptance reduces to Eq. (4.7).
// Differences use the minimum image on the torus.
//
// No trigonometry: z - y is x - y rotated by theta. With t = tan(theta / 2), cos theta = (1 - t^2)/(1 + t^2)
// and sin theta = 2t/(1 + t^2), and the wrapped Cauchy law is t = ((1 - rho)/(1 + rho)) C with C a standard
// Cauchy variate (inverting the CDF gives theta = 2 atan(((1 - rho)/(1 + rho)) tan(pi (u - 1/2)))). C is the
// ratio a/b of a point (a, b) uniform in the unit disk (its angle is uniform), drawn by rejection.
// Only valid as the second stage of drmlt with type="orbital" after a circularly symmetric first stage
// (kelemen_pair, gaussian, or a large step).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
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
    bool uses_rejected() const override { return true; }
    bool symmetric() const override { return false; }  // singular: has no density
    void sample_pair(uint64_t, const double* x, double* y, Random&) const override {
        y[0] = x[0];  // never used as a first stage
        y[1] = x[1];
    }
    double log_density(Coords, Coords) const override { return -Inf; }

    void sample_second_pair(uint64_t, const double* x, const double* y, double* z, Random& rng) const override {
        // w = x - y (minimum image); z = y + R(theta) w.
        const double w1 = -torus_delta(x[0], y[0]), w2 = -torus_delta(x[1], y[1]);
        const Vec2d cs = rotation(rng);
        z[0] = torus_wrap(x[0] - w1 + cs.x * w1 - cs.y * w2);
        z[1] = torus_wrap(x[1] - w2 + cs.y * w1 + cs.x * w2);
    }
    double log_density_second(Coords, Coords, Coords) const override { return -Inf; }

    /// (cos theta, sin theta) of a wrapped-Cauchy angle.
    Vec2d rotation(Random& rng) const {
        for (;;) {
            const double a = signed_unit(rng), b = signed_unit(rng);
            if (a * a + b * b >= 1 || b == 0) continue;
            // t = s a / b; cos = (1 - t^2)/(1 + t^2) = (b^2 - s^2 a^2)/(b^2 + s^2 a^2), sin = 2 s a b / (...).
            const double sa = m_tan_scale * a, den = b * b + sa * sa;
            return {(b * b - sa * sa) / den, 2 * sa * b / den};
        }
    }
    /// Wrapped-Cauchy angle in (-pi, pi] by inversion (used by the tests as the reference law).
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
