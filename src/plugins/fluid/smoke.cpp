// smoke: a passive density for 3D simulations (<scalar type="smoke"> with dimension = 3). The density is carried
// along exactly the backtraces the solver computes for the vorticity (no diffusion), starts at `density` inside a
// sphere and is fed at `rate` per unit time inside it; it is written as the OpenVDB grid "density" of each frame
// (the thesis renders its smoke with Blender's volume shader, Fig. 5.12) and its integral as the CSV's smoke_mass.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <scalar type="smoke"><point name="center" x="0" y="0" z="-1"/><float name="rate" value="2"/></scalar>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/fields.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class Smoke final : public SmokeSpec3 {
public:
    explicit Smoke(const Properties& props)
        : m_center(props.get_point("center")),
          m_radius(props.get_float("radius", 1e-300, 1e300)),
          m_density(props.get_float("density", 0.0, 1e150)),
          m_rate(props.get_float("rate", 0.0, 1e150)) {
        for (int a = 0; a < 3; ++a)
            if (!std::isfinite(m_center[a])) props.error("center", "must be finite");
    }
    Vec3d center() const override { return m_center; }
    double radius() const override { return m_radius; }
    double initial_density() const override { return m_density; }
    double rate() const override { return m_rate; }
    std::string description() const override {
        return fmt::format("smoke(radius {:g}, density {:g}, rate {:g})", m_radius, m_density, m_rate);
    }

private:
    Vec3d m_center;
    double m_radius, m_density, m_rate;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::Smoke, "scalar", "smoke",
              "3D passive smoke density carried along the solver's backtraces, from a spherical source.",
              kelvin::param::point("center", kelvin::Vec3d(0.0), "centre of the source sphere"),
              kelvin::param::real("radius", 0.25, "radius of the source sphere"),
              kelvin::param::real("density", 1.0, "density inside the sphere at t = 0"),
              kelvin::param::real("rate", 0.0, "density added per unit time inside the sphere"));
