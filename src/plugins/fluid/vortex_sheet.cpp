// vortex_sheet: a shear layer u(y) = U tanh((y - y0) / delta) (Kelvin–Helmholtz), in vorticity form
//
//     omega(x, y) = -(U / delta) sech^2((y - y0 - eta(x)) / delta),   eta(x) = epsilon sin(2 pi m (x - min.x) / L_x)
//
// (omega = dv/dx - du/dy; the fluid above moves to +x at U, below to -x). The sheet is displaced by a small
// sinusoid of m wavelengths across the box (`perturbation` epsilon, `modes` m) that seeds the roll-up; a thin
// sheet is a small thickness (resolve it with at least two cells). The circulation per unit length is -2U.
//
// `double_layer` adds a second layer of opposite sign half a box higher (y0 + L_y / 2, wrapped into the box)
// with the same perturbation: the periodic double shear layer of Bell, Colella & Glaz (1989), whose mean
// vorticity is zero, so that a periodic box sees exactly the two layers. A single layer on a periodic box is
// accepted too (the periodic Biot–Savart kernel removes its mean vorticity: the far field is a weak uniform
// shear); on an open box the layer ends at the box edges, which roll up as well.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <vorticity type="vortex_sheet"><float name="thickness" value="0.08"/><integer name="modes"
//     value="2"/></vorticity>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/fields.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class VortexSheet final : public VorticityField {
public:
    explicit VortexSheet(const Properties& props)
        : m_y0(props.get_float("y", -1e300, 1e300)),
          m_u(props.get_float("velocity", -1e12, 1e12)),
          m_delta(props.get_float("thickness")),
          m_eps(props.get_float("perturbation", -1e300, 1e300)),
          m_modes(int(props.get_int("modes", 0, 1 << 20))),
          m_double(props.get_bool("double_layer")) {
        if (!(m_delta > 0) || !std::isfinite(m_delta)) props.error("thickness", "must be positive and finite");
    }

    void bind_domain(const Domain2& d) override { m_domain = d; }

    double vorticity(const Vec2d& x) const override {
        const double lx = m_domain.size().x, ly = m_domain.size().y;
        const double eta = m_eps * std::sin(2 * Pi * m_modes * (x.x - m_domain.min.x) / lx);
        // On a periodic box, the nearest image of each layer (the profile decays as exp(-2|r|/delta): the
        // farther images are negligible for any layer thinner than the box).
        auto nearest = [&](double r) { return m_domain.periodic ? r - ly * std::nearbyint(r / ly) : r; };
        double w = layer(nearest(x.y - m_y0 - eta));
        if (m_double) w -= layer(nearest(x.y - (m_y0 + 0.5 * ly) - eta));
        return w;
    }

    void check_domain(const Domain2& d) const override {
        if (m_delta < 1e-3 * d.size().y)
            log_warn("vortex_sheet: thickness {:g} is below 1/1000 of the box height; resolve it with two cells",
                     m_delta);
        if (m_y0 < d.min.y || m_y0 > d.max.y)
            log_warn("vortex_sheet: the layer at y = {:g} lies outside the box {}", m_y0, d.to_string());
        if (!d.periodic)
            log_warn(
                "vortex_sheet on an open box: the layer ends at the box edges (which roll up too); a periodic box "
                "gives the classic Kelvin–Helmholtz layer");
    }

    std::string strength_parameter() const override { return "velocity"; }
    std::string description() const override {
        return fmt::format("vortex_sheet(y={:g}, U={:g}, thickness={:g}, perturbation={:g}, modes={}{})", m_y0, m_u,
                           m_delta, m_eps, m_modes, m_double ? ", double layer" : "");
    }

private:
    double layer(double r) const {
        const double c = std::cosh(r / m_delta);
        return -(m_u / m_delta) / (c * c);
    }
    double m_y0, m_u, m_delta, m_eps;
    int m_modes;
    bool m_double;
    Domain2 m_domain;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::VortexSheet, "vorticity", "vortex_sheet",
              "Shear layer u = U tanh((y - y0)/delta) with a sinusoidal perturbation (Kelvin–Helmholtz roll-up); "
              "optionally the periodic double layer.",
              kelvin::param::real("y", 0.0, "y0, the layer's height"),
              kelvin::param::real("velocity", 1.0, "U: +U above the layer, -U below"),
              kelvin::param::real("thickness", 0.05, "delta, tanh thickness"),
              kelvin::param::real("perturbation", 0.01, "epsilon, amplitude of the layer's displacement"),
              kelvin::param::integer("modes", 2, "m, wavelengths of the perturbation across the box"),
              kelvin::param::boolean("double_layer", false,
                                     "add the opposite layer half a box higher (periodic double shear layer)"));
