// sphere: a 3D ball as a boundary (exact distance | |p - c| - r |; knows its inside).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <boundary type="sphere"><point name="center" x="0" y="0" z="0"/><float name="radius" value="1"/></boundary>
#include "boundary_common.h"

namespace kelvin::wos::boundaries {
namespace {

class Sphere final : public Boundary3 {
public:
    explicit Sphere(const Properties& props) : Boundary3(props, true) {
        m_s.center = props.get_point("center");
        for (int i = 0; i < 3; ++i)
            if (!std::isfinite(m_s.center[i])) props.error("center", "must be finite");
        m_s.radius = props.get_float("radius", 0.0, 1e300);
        if (!(m_s.radius > 0)) props.error("radius", "must be positive");
        if (m_role.moving()) props.error("velocity", "3D boundaries do not move (rigid motion is 2D only)");
    }
    double distance(const Vec3d& p) const override { return m_s.distance(p); }
    BoundaryHit<3> closest(const Vec3d& p) const override { return m_s.closest(p); }
    bool has_inside() const override { return true; }
    bool inside3(const Vec3d& p) const override { return glm::length(p - m_s.center) < m_s.radius; }
    std::pair<Vec3d, Vec3d> bounds() const override { return {m_s.center - m_s.radius, m_s.center + m_s.radius}; }
    std::string description() const override {
        return fmt::format("sphere (centre ({:g}, {:g}, {:g}), radius {:g})", m_s.center.x, m_s.center.y, m_s.center.z,
                           m_s.radius);
    }

private:
    wos::SphereBoundary<3> m_s;
};

}  // namespace
}  // namespace kelvin::wos::boundaries

KELVIN_BOUNDARY_PLUGIN(kelvin::wos::boundaries::Sphere, "sphere", "3D ball, exact distance, knows its inside.",
                       kelvin::param::point("center", kelvin::Vec3d(0.0), "centre"),
                       kelvin::param::real("radius", 0.25, "radius"));
