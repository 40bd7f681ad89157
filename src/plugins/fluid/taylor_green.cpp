// taylor_green: the steady Taylor–Green cellular flow used by the thesis' convergence study (Figure 5.15),
//
//     omega(0, x, y) = A sin(k x) cos(k y),
//     u = -(A / (2k)) sin(k x) sin(k y),   v = -(A / (2k)) cos(k x) cos(k y)
//
// (omega = dv/dx - du/dy, positive counter-clockwise). omega is an eigenfunction of the Laplacian
// (-Laplacian omega = 2 k^2 omega) and a function of the stream function, so the inviscid flow is steady and
// the viscous flow decays as omega(t) = exp(-2 k^2 nu t) omega(0) (exp(-2 nu t) for k = 1). The exact
// solution is for a periodic box whose sides are multiples of 2 pi / k, e.g. [-pi, pi]^2.
//
// In 3D (dimension = 3) it is the 3D Taylor–Green vortex, the classic transition-to-turbulence initial state,
//
//     u = (A / (2k)) (sin kx cos ky cos kz, -cos kx sin ky cos kz, 0),
//     omega = (A / 2) (-cos kx sin ky sin kz, -sin kx cos ky sin kz, 2 sin kx sin ky cos kz),
//
// scaled so that omega_z on the plane z = 0 is the 2D field's A sin kx sin ky (up to a phase); the exact
// solution is known at t = 0 only.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <vorticity type="taylor_green"><float name="amplitude" value="1"/></vorticity>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/fields.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class TaylorGreen final : public VorticityField, public VorticityField3 {
public:
    explicit TaylorGreen(const Properties& props)
        : m_a(props.get_float("amplitude", -1e12, 1e12)), m_k(double(props.get_int("wavenumber", 1, 1 << 16))) {}

    double vorticity(const Vec2d& x) const override { return m_a * std::sin(m_k * x.x) * std::cos(m_k * x.y); }

    std::optional<double> exact_vorticity(double t, const Vec2d& x, double nu) const override {
        return decay(t, nu) * vorticity(x);
    }
    std::optional<Vec2d> exact_velocity(double t, const Vec2d& x, double nu) const override {
        const double c = -decay(t, nu) * m_a / (2 * m_k);
        return Vec2d(c * std::sin(m_k * x.x) * std::sin(m_k * x.y), c * std::cos(m_k * x.x) * std::cos(m_k * x.y));
    }

    bool exact_on(const Domain2& d) const override {
        const double period = 2 * Pi / m_k;
        return d.periodic && fits_period(d.size().x, period) && fits_period(d.size().y, period);
    }
    void check_domain(const Domain2& d) const override {
        const double period = 2 * Pi / m_k;
        auto fits = [&](double len) { return fits_period(len, period); };
        if (!d.periodic)
            log_warn(
                "taylor_green on an open domain: the field is cut at the box and the flow is no longer the "
                "exact Taylor–Green solution (use <boolean name=\"periodic\" value=\"true\"/>)");
        else if (!fits(d.size().x) || !fits(d.size().y))
            log_warn(
                "taylor_green: the periodic box {} is not a multiple of the period 2 pi / k = {:g}; the "
                "field is discontinuous across the box edges",
                d.to_string(), period);
    }

    std::string strength_parameter() const override { return "amplitude"; }
    std::string strength_parameter3() const override { return "amplitude"; }
    std::string description() const override { return fmt::format("taylor_green(amplitude={:g}, k={:g})", m_a, m_k); }

    // ----- 3D
    Vec3d vorticity3(const Vec3d& x) const override {
        const double k = m_k, sx = std::sin(k * x.x), cx = std::cos(k * x.x), sy = std::sin(k * x.y),
                     cy = std::cos(k * x.y), sz = std::sin(k * x.z), cz = std::cos(k * x.z);
        return 0.5 * m_a * Vec3d(-cx * sy * sz, -sx * cy * sz, 2 * sx * sy * cz);
    }
    std::optional<Vec3d> exact_vorticity3(double t, const Vec3d& x, double) const override {
        if (t != 0) return std::nullopt;
        return vorticity3(x);
    }
    std::optional<Vec3d> exact_velocity3(double t, const Vec3d& x, double) const override {
        if (t != 0) return std::nullopt;
        const double k = m_k, c = m_a / (2 * k);
        return c * Vec3d(std::sin(k * x.x) * std::cos(k * x.y) * std::cos(k * x.z),
                         -std::cos(k * x.x) * std::sin(k * x.y) * std::cos(k * x.z), 0.0);
    }
    void check_domain3(const Domain3& d) const override {
        const double period = 2 * Pi / m_k;
        auto fits = [&](double len) { return fits_period(len, period); };
        if (!d.periodic)
            log_warn("taylor_green on an open 3D domain: the field is cut at the box (use a periodic box)");
        else if (!fits(d.size().x) || !fits(d.size().y) || !fits(d.size().z))
            log_warn("taylor_green: the periodic box {} is not a multiple of the period 2 pi / k = {:g}", d.to_string(),
                     period);
    }
    std::string description3() const override { return "3D " + description(); }

private:
    double decay(double t, double nu) const { return std::exp(-2 * m_k * m_k * nu * t); }
    double m_a, m_k;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::TaylorGreen, "vorticity", "taylor_green",
              "Steady Taylor–Green cells omega = A sin(kx) cos(ky) (decays as exp(-2 k^2 nu t) when viscous).",
              kelvin::param::real("amplitude", 1.0, "A, the peak vorticity"),
              kelvin::param::integer("wavenumber", 1,
                                     "k (>= 1); the exact solution needs a periodic box of "
                                     "sides multiple of 2 pi / k"));
