// lamb_oseen: a Gaussian (Lamb–Oseen) vortex,
//
//     omega(t, r) = Gamma / (pi s^2) exp(-r^2 / s^2),   s^2(t) = sigma^2 + 4 nu t,
//     u_theta(t, r) = Gamma / (2 pi r) (1 - exp(-r^2 / s^2)),
//
// the exact free-space solution of the Navier–Stokes equations: steady when inviscid, with a core that
// spreads as s^2 = sigma^2 + 4 nu t when viscous. Gamma > 0 turns counter-clockwise. The second moment
// int omega r^2 / int omega equals s^2, which is how the tests measure the core.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <vorticity type="lamb_oseen"><float name="radius" value="0.15"/></vorticity>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/fields.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class LambOseen final : public VorticityField {
public:
    explicit LambOseen(const Properties& props)
        : m_gamma(props.get_float("circulation", -1e12, 1e12)), m_sigma(props.get_float("radius")) {
        Vec3d c = props.get_point("center");
        if (c.z != 0) props.error("center", "a 2D simulation takes a centre with z = 0");
        if (!std::isfinite(c.x) || !std::isfinite(c.y)) props.error("center", "must be finite");
        m_center = {c.x, c.y};
        if (!(m_sigma > 0) || !std::isfinite(m_sigma)) props.error("radius", "must be positive and finite");
    }

    double vorticity(const Vec2d& x) const override { return omega(x, m_sigma * m_sigma); }

    std::optional<double> exact_vorticity(double t, const Vec2d& x, double nu) const override {
        return omega(x, core2(t, nu));
    }
    std::optional<Vec2d> exact_velocity(double t, const Vec2d& x, double nu) const override {
        const Vec2d r = x - m_center;
        const double r2 = glm::dot(r, r), s2 = core2(t, nu);
        if (r2 == 0) return Vec2d(0.0);
        const double f = m_gamma / (2 * Pi * r2) * -std::expm1(-r2 / s2);
        return Vec2d(-r.y * f, r.x * f);
    }

    bool exact_on(const Domain2& d) const override { return !d.periodic; }
    void check_domain(const Domain2& d) const override {
        if (d.periodic)
            log_warn(
                "lamb_oseen on a periodic domain: the exact solution is for free space (the periodic images "
                "and the neutralising background change the flow)");
        const double margin =
            std::min({m_center.x - d.min.x, d.max.x - m_center.x, m_center.y - d.min.y, d.max.y - m_center.y});
        if (margin < 3 * m_sigma)
            log_warn("lamb_oseen: the core (radius {:g}) is closer than 3 radii to the box edge; its tail is cut",
                     m_sigma);
    }

    std::string strength_parameter() const override { return "circulation"; }
    std::string description() const override {
        return fmt::format("lamb_oseen(center=({:g}, {:g}), circulation={:g}, radius={:g})", m_center.x, m_center.y,
                           m_gamma, m_sigma);
    }

private:
    double core2(double t, double nu) const { return m_sigma * m_sigma + 4 * nu * t; }
    double omega(const Vec2d& x, double s2) const {
        const Vec2d r = x - m_center;
        return m_gamma / (Pi * s2) * std::exp(-glm::dot(r, r) / s2);
    }
    Vec2d m_center{0.0};
    double m_gamma, m_sigma;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::LambOseen, "vorticity", "lamb_oseen",
              "Gaussian (Lamb–Oseen) vortex; exact free-space solution, core s^2 = sigma^2 + 4 nu t.",
              kelvin::param::point("center", kelvin::Vec3d(0.0), "vortex centre (z = 0)"),
              kelvin::param::real("circulation", 1.0, "Gamma, total circulation (> 0: counter-clockwise)"),
              kelvin::param::real("radius", 0.2, "sigma, core radius at t = 0"));
