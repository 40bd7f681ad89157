// abc: the Arnold–Beltrami–Childress flow on a periodic box (3D),
//
//     u = (A sin kz + C cos ky,  B sin kx + A cos kz,  C sin ky + B cos kx),   omega = curl u = k u.
//
// omega is parallel to u (a Beltrami field), so advection and stretching cancel exactly: the inviscid flow is
// steady, and the viscous flow decays as exp(-nu k^2 t) (energy as exp(-2 nu k^2 t)). Any error in the
// advection or in the stretching term shows as drift. The exact solution needs a periodic box of sides
// multiple of 2 pi / k, e.g. [0, 2 pi]^3.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <vorticity type="abc"><float name="A" value="1"/><float name="B" value="1"/><float name="C"
//     value="1"/></vorticity>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/fields.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class AbcFlow final : public Object, public VorticityField3 {
public:
    explicit AbcFlow(const Properties& props)
        : m_a(props.get_float("A", -1e150, 1e150)),
          m_b(props.get_float("B", -1e150, 1e150)),
          m_c(props.get_float("C", -1e150, 1e150)),
          m_k(double(props.get_int("wavenumber", 1, 1 << 16))) {}

    Vec3d velocity(const Vec3d& x) const {
        const double k = m_k;
        return {m_a * std::sin(k * x.z) + m_c * std::cos(k * x.y), m_b * std::sin(k * x.x) + m_a * std::cos(k * x.z),
                m_c * std::sin(k * x.y) + m_b * std::cos(k * x.x)};
    }
    Vec3d vorticity3(const Vec3d& x) const override { return m_k * velocity(x); }
    std::optional<Vec3d> exact_vorticity3(double t, const Vec3d& x, double nu) const override {
        return decay(t, nu) * vorticity3(x);
    }
    std::optional<Vec3d> exact_velocity3(double t, const Vec3d& x, double nu) const override {
        return decay(t, nu) * velocity(x);
    }

    void check_domain3(const Domain3& d) const override {
        const double period = 2 * Pi / m_k;
        auto fits = [&](double len) { return fits_period(len, period); };
        if (!d.periodic)
            log_warn(
                "abc on an open domain: the field is cut at the box and is no longer the exact ABC flow (use "
                "<boolean name=\"periodic\" value=\"true\"/>)");
        else if (!fits(d.size().x) || !fits(d.size().y) || !fits(d.size().z))
            log_warn("abc: the periodic box {} is not a multiple of the period 2 pi / k = {:g}", d.to_string(), period);
    }

    std::string strength_parameter3() const override {  // the largest coefficient
        const double a = std::abs(m_a), b = std::abs(m_b), c = std::abs(m_c);
        return a >= b && a >= c ? "A" : (b >= c ? "B" : "C");
    }
    std::string description3() const override {
        return fmt::format("abc(A={:g}, B={:g}, C={:g}, k={:g})", m_a, m_b, m_c, m_k);
    }

private:
    double decay(double t, double nu) const { return std::exp(-m_k * m_k * nu * t); }
    double m_a, m_b, m_c, m_k;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::AbcFlow, "vorticity", "abc",
              "3D Arnold–Beltrami–Childress flow (omega = k u; steady inviscid, decays as exp(-nu k^2 t)).",
              kelvin::param::real("A", 1.0, "coefficient A"), kelvin::param::real("B", 1.0, "coefficient B"),
              kelvin::param::real("C", 1.0, "coefficient C"),
              kelvin::param::integer("wavenumber", 1, "k (>= 1); periodic box of sides multiple of 2 pi / k"));
