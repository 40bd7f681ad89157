// box: an out-of-tree proposal kernel (a `<mutation>` plugin), to show how a researcher adds one. Every
// primary-sample coordinate moves by an independent uniform step in [-radius, radius], wrapped into [0, 1).
// The kernel is a symmetric random walk (the property every chain needs of its first stage, chain.h), with
// density (1 / (2 radius))^n on the torus for radius <= 1/2. A chain asks a kernel to move one coordinate pair
// at a time (sample_pair), only the pairs a path reads.
//
// As the second stage of delayed rejection (a small, timid move after a rejected bold one):
//
//     <integrator type="drmlt">
//         <string name="type" value="mira"/>
//         <mutation name="second" type="box"><float name="radius" value="0.002"/></mutation>
//     </integrator>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/mutation.h>

#include <cmath>

namespace box_example {

class BoxMutation final : public kelvin::Mutation {
public:
    explicit BoxMutation(const kelvin::Properties& props) : m_radius(props.get_float("radius")) {
        if (!(m_radius > 0 && m_radius <= 0.5)) props.error("radius", "must be in (0, 1/2]");
        m_log_density = -std::log(2 * m_radius);
    }

    void sample_pair(uint64_t, const double* x, double* y, kelvin::Random& rng) const override {
        for (int i = 0; i < 2; ++i) y[i] = kelvin::torus_wrap(x[i] + m_radius * (2 * rng.next_double() - 1));
    }
    // Minimum-image differences: the density is the same across the seam of the torus as anywhere else.
    double log_density(kelvin::Coords from, kelvin::Coords to) const override {
        for (std::size_t i = 0; i < from.size(); ++i)
            if (std::abs(kelvin::torus_delta(from[i], to[i])) > m_radius) return -kelvin::Inf;
        return double(from.size()) * m_log_density;
    }
    double scale() const override { return m_radius; }

private:
    double m_radius, m_log_density;
};

}  // namespace box_example

KELVIN_PLUGIN(box_example::BoxMutation, "mutation", "box",
              "Uniform step in a cube of half-width `radius` around the state. Out-of-tree example.",
              kelvin::param::real("radius", 1.0 / 256, "half-width of the step, in (0, 1/2]"));
