// vortex_ring: thin-cored vortex rings with a Gaussian core (3D), the initial condition of the thesis'
// leapfrogging rings (Fig. 5.12 top). For a ring of centre c, unit normal n, radius R, circulation Gamma and
// core sigma, a point x at axial offset z = (x - c) . n and distance rho from the axis has
//
//     omega(x) = Gamma / (pi sigma^2) exp(-s^2 / sigma^2) e_theta,   s^2 = (rho - R)^2 + z^2,
//
// e_theta = n x (x - c - z n) / rho, so that a positive circulation moves the ring along +n. Its translation
// speed for sigma << R is Saffman's U = Gamma / (4 pi R) (ln(8 R / sigma) - 0.558) (Saffman 1970, the
// Gaussian core of this normalisation). Several coaxial rings: `offsets` lists their centres' positions along
// n relative to `center` (the leapfrog scene uses two).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <vorticity type="vortex_ring"><float name="radius" value="1"/><float name="core" value="0.2"/></vorticity>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/fields.h>

#include <fmt/format.h>

#include <cmath>
#include <sstream>

namespace kelvin::fluid {
namespace {

class VortexRing final : public Object, public VorticityField3, public VortexRings3 {
public:
    explicit VortexRing(const Properties& props)
        : m_center(props.get_point("center")),
          m_radius(props.get_float("radius", 1e-300, 1e300)),
          m_gamma(props.get_float("circulation", -1e150, 1e150)),
          m_core(props.get_float("core", 1e-300, 1e300)) {
        const Vec3d n = props.get_vector("normal");
        const double len = glm::length(n);
        if (!(len > 0) || !std::isfinite(len)) props.error("normal", "must be a non-zero finite vector");
        m_normal = n / len;
        for (int a = 0; a < 3; ++a)
            if (!std::isfinite(m_center[a])) props.error("center", "must be finite");
        if (!(m_core < m_radius))
            props.error("core", fmt::format("must be smaller than the radius ({:g} >= {:g})", m_core, m_radius));
        std::istringstream in(props.get_string("offsets"));
        std::string tok;
        while (in >> tok) {
            char* end = nullptr;
            const double o = std::strtod(tok.c_str(), &end);
            if (end == tok.c_str() || *end != '\0' || !std::isfinite(o))
                props.error("offsets", fmt::format("'{}' is not a finite number", tok));
            m_offsets.push_back(o);
        }
        if (m_offsets.empty()) props.error("offsets", "needs at least one offset");
        m_peak = m_gamma / (Pi * m_core * m_core);
    }

    Vec3d vorticity3(const Vec3d& x) const override {
        Vec3d w(0.0);
        for (double o : m_offsets) {
            const Vec3d p = x - (m_center + o * m_normal);
            const double z = glm::dot(p, m_normal);
            const Vec3d radial = p - z * m_normal;
            const double rho = glm::length(radial);
            if (!(rho > 0)) continue;  // on the axis: e_theta undefined, and exp(-R^2/sigma^2) is negligible
            const double s2 = (rho - m_radius) * (rho - m_radius) + z * z;
            const double mag = m_peak * std::exp(-s2 / (m_core * m_core));
            w += (mag / rho) * glm::cross(m_normal, radial);
        }
        return w;
    }

    void check_domain3(const Domain3& d) const override {
        (void)d;  // rings may start anywhere; vorticity leaving an open box is lost (documented)
    }

    std::string strength_parameter3() const override { return "circulation"; }
    // For the ring-core columns of diagnostics.csv (ring_cores.h).
    RingGeometry ring_geometry() const override { return {m_center, m_normal, m_radius, m_gamma, m_core, m_offsets}; }
    std::string description3() const override {
        return fmt::format("vortex_ring(R={:g}, Gamma={:g}, core={:g}, rings={})", m_radius, m_gamma, m_core,
                           m_offsets.size());
    }

private:
    Vec3d m_center, m_normal{0, 0, 1};
    double m_radius, m_gamma, m_core, m_peak = 0;
    std::vector<double> m_offsets;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::VortexRing, "vorticity", "vortex_ring",
              "3D vortex rings with a Gaussian core (Saffman speed Gamma/(4 pi R) (ln(8R/sigma) - 0.558)).",
              kelvin::param::point("center", kelvin::Vec3d(0.0), "centre of the first ring"),
              kelvin::param::vector("normal", kelvin::Vec3d(0.0, 0.0, 1.0), "ring axis (direction of motion)"),
              kelvin::param::real("radius", 1.0, "ring radius R"),
              kelvin::param::real("circulation", 1.0, "circulation Gamma"),
              kelvin::param::real("core", 0.1, "Gaussian core radius sigma (< R)"),
              kelvin::param::string("offsets", "0", "positions of coaxial rings along the normal"));
