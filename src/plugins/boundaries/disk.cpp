// disk: a 2D disk as a solid boundary (exact distance | |p - c| - r |; knows its inside, so it can be a
// container with fluid = "inside"). A disk smaller than a cache cell is fine (Figure 5.14): walks find it by
// its distance, whatever the grid.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <boundary type="disk"><point name="center" x="-0.5" y="0"/><float name="radius" value="0.1"/></boundary>
#include "boundary_common.h"

namespace kelvin::wos::boundaries {
namespace {

class Disk final : public Boundary2 {
public:
    explicit Disk(const Properties& props) : Boundary2(props, true) {
        const Vec3d c = props.get_point("center");
        if (!std::isfinite(c.x) || !std::isfinite(c.y)) props.error("center", "must be finite");
        m_disk.center = {c.x, c.y};
        m_disk.radius = props.get_float("radius", 0.0, 1e300);
        if (!(m_disk.radius > 0)) props.error("radius", "must be positive");
    }
    double distance(const Vec2d& p) const override { return m_disk.distance(p); }
    BoundaryHit<2> closest(const Vec2d& p) const override { return m_disk.closest(p); }
    bool has_inside() const override { return true; }
    bool inside2(const Vec2d& p) const override {
        const Vec2d d = p - m_disk.center;
        return glm::dot(d, d) < m_disk.radius * m_disk.radius;
    }
    std::pair<Vec3d, Vec3d> bounds() const override {
        const double r = m_disk.radius;
        return {{m_disk.center.x - r, m_disk.center.y - r, 0}, {m_disk.center.x + r, m_disk.center.y + r, 0}};
    }
    std::vector<std::array<Vec2d, 2>> segments2(double max_length) const override {
        std::vector<std::array<Vec2d, 2>> out;
        arc_chords(m_disk.center, m_disk.radius, 0, 2 * Pi, max_length, 8, out);
        return out;
    }
    std::string description() const override {
        return fmt::format("disk (centre ({:g}, {:g}), radius {:g})", m_disk.center.x, m_disk.center.y, m_disk.radius);
    }

private:
    wos::SphereBoundary<2> m_disk;
};

}  // namespace
}  // namespace kelvin::wos::boundaries

KELVIN_BOUNDARY_PLUGIN(kelvin::wos::boundaries::Disk, "disk", "2D disk, exact distance, knows its inside.",
                       kelvin::param::point("center", kelvin::Vec3d(0.0), "centre (z ignored)"),
                       kelvin::param::real("radius", 0.25, "radius"));
