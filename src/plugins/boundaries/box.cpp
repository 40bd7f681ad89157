// box: an axis-aligned rectangle (2D) or box (3D) as a solid boundary, with its exact distance (outside: to
// the box; inside: to the nearest face). Knows its inside, so it can also be a container (fluid = "inside").
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <boundary type="box"><point name="min" x="-0.1" y="-0.1"/><point name="max" x="0.1" y="0.1"/></boundary>
#include "boundary_common.h"

namespace kelvin::wos::boundaries {
namespace {

void read_corners(const Properties& props, int dim, Vec3d& lo, Vec3d& hi) {
    lo = props.get_point("min");
    hi = props.get_point("max");
    for (int i = 0; i < dim; ++i) {
        if (!std::isfinite(lo[i]) || !std::isfinite(hi[i])) props.error("min", "corners must be finite");
        if (!(hi[i] > lo[i])) props.error("max", "must exceed min along every axis");
    }
}

class Box2 final : public Boundary2 {
public:
    explicit Box2(const Properties& props) : Boundary2(props, true) {
        Vec3d lo, hi;
        read_corners(props, 2, lo, hi);
        m_box = {{lo.x, lo.y}, {hi.x, hi.y}};
    }
    double distance(const Vec2d& p) const override { return m_box.distance(p); }
    BoundaryHit<2> closest(const Vec2d& p) const override { return m_box.closest(p); }
    bool has_inside() const override { return true; }
    bool inside2(const Vec2d& p) const override {
        return p.x > m_box.lo.x && p.x < m_box.hi.x && p.y > m_box.lo.y && p.y < m_box.hi.y;
    }
    std::pair<Vec3d, Vec3d> bounds() const override {
        return {{m_box.lo.x, m_box.lo.y, 0}, {m_box.hi.x, m_box.hi.y, 0}};
    }
    std::vector<std::array<Vec2d, 2>> segments2(double) const override {
        const Vec2d a = m_box.lo, c = m_box.hi, b(c.x, a.y), d(a.x, c.y);
        return {{a, b}, {b, c}, {c, d}, {d, a}};
    }
    std::string description() const override {
        return fmt::format("box [{:g}, {:g}] x [{:g}, {:g}]", m_box.lo.x, m_box.hi.x, m_box.lo.y, m_box.hi.y);
    }

private:
    wos::BoxBoundary<2> m_box;
};

class Box3 final : public Boundary3 {
public:
    explicit Box3(const Properties& props) : Boundary3(props, true) {
        Vec3d lo, hi;
        read_corners(props, 3, lo, hi);
        m_box = {lo, hi};
        if (m_role.moving()) props.error("velocity", "3D boundaries do not move (rigid motion is 2D only)");
    }
    double distance(const Vec3d& p) const override { return m_box.distance(p); }
    BoundaryHit<3> closest(const Vec3d& p) const override { return m_box.closest(p); }
    bool has_inside() const override { return true; }
    bool inside3(const Vec3d& p) const override {
        return glm::all(glm::greaterThan(p, m_box.lo)) && glm::all(glm::lessThan(p, m_box.hi));
    }
    std::pair<Vec3d, Vec3d> bounds() const override { return {m_box.lo, m_box.hi}; }
    std::string description() const override { return "box (3D)"; }

private:
    wos::BoxBoundary<3> m_box;
};

/// One plugin name for both dimensions, chosen by `dimension`.
using Box = ByDimension<Box2, Box3>;

}  // namespace
}  // namespace kelvin::wos::boundaries

KELVIN_BOUNDARY_PLUGIN(kelvin::wos::boundaries::Box, "box",
                       "Axis-aligned rectangle (2D) or box (3D), exact distance, knows its inside.",
                       kelvin::param::integer("dimension", 2, "2 or 3"),
                       kelvin::param::point("min", kelvin::Vec3d(-0.5), "corner"),
                       kelvin::param::point("max", kelvin::Vec3d(0.5), "opposite corner"));
