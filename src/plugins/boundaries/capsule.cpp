// capsule: the points within `radius` of the segment [a, b] (a stadium in 2D, a capsule in 3D), exact distance
// | |p - closest point of [a, b]| - radius |. Knows its inside. a = b gives a disk or ball.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <boundary type="capsule"><point name="a" x="-0.3" y="0"/><point name="b" x="0.3" y="0.1"/>
//         <float name="radius" value="0.05"/></boundary>
#include "boundary_common.h"

namespace kelvin::wos::boundaries {
namespace {

template <int D>
struct CapsuleGeometry {
    wos::Vec<D> a, b;
    double r = 0.1;
    wos::Vec<D> axis_point(const wos::Vec<D>& p) const {
        const wos::Vec<D> ab = b - a;
        const double l2 = glm::dot(ab, ab);
        const double t = l2 > 0 ? std::clamp(glm::dot(p - a, ab) / l2, 0.0, 1.0) : 0.0;
        return a + t * ab;
    }
    double signed_distance(const wos::Vec<D>& p) const { return glm::length(p - axis_point(p)) - r; }
    BoundaryHit<D> closest(const wos::Vec<D>& p) const {
        const wos::Vec<D> q = axis_point(p);
        wos::Vec<D> d = p - q;
        const double l = glm::length(d);
        wos::Vec<D> n(0.0);
        if (l > 0) {
            n = d / l;
        } else {  // on the axis: any perpendicular; pick one
            const wos::Vec<D> ab = b - a;
            if constexpr (D == 2) {
                n = glm::length(ab) > 0 ? glm::normalize(wos::Vec<D>(-ab.y, ab.x)) : wos::Vec<D>(1.0, 0.0);
            } else {
                wos::Vec<D> t = glm::cross(ab, wos::Vec<D>(1, 0, 0));
                if (glm::length(t) == 0) t = glm::cross(ab, wos::Vec<D>(0, 1, 0));
                n = glm::length(t) > 0 ? glm::normalize(t) : wos::Vec<D>(1, 0, 0);
            }
        }
        return {q + r * n, n, 0};
    }
};

template <int D>
CapsuleGeometry<D> read_capsule(const Properties& props) {
    const Vec3d a = props.get_point("a"), b = props.get_point("b");
    CapsuleGeometry<D> c;
    for (int i = 0; i < D; ++i) {
        if (!std::isfinite(a[i]) || !std::isfinite(b[i])) props.error("a", "end points must be finite");
        c.a[i] = a[i];
        c.b[i] = b[i];
    }
    c.r = props.get_float("radius", 0.0, 1e300);
    if (!(c.r > 0)) props.error("radius", "must be positive");
    return c;
}

class Capsule2 final : public Boundary2 {
public:
    explicit Capsule2(const Properties& props) : Boundary2(props, true), m_c(read_capsule<2>(props)) {}
    double distance(const Vec2d& p) const override { return std::abs(m_c.signed_distance(p)); }
    BoundaryHit<2> closest(const Vec2d& p) const override { return m_c.closest(p); }
    bool has_inside() const override { return true; }
    bool inside2(const Vec2d& p) const override { return m_c.signed_distance(p) < 0; }
    std::pair<Vec3d, Vec3d> bounds() const override {
        const Vec2d lo = glm::min(m_c.a, m_c.b) - m_c.r, hi = glm::max(m_c.a, m_c.b) + m_c.r;
        return {{lo.x, lo.y, 0}, {hi.x, hi.y, 0}};
    }
    std::string description() const override { return fmt::format("capsule (radius {:g})", m_c.r); }
    /// Two half circles about the end points joined by the two sides.
    std::vector<std::array<Vec2d, 2>> segments2(double max_length) const override {
        const Vec2d ab = m_c.b - m_c.a;
        const double phi = glm::length(ab) > 0 ? std::atan2(ab.y, ab.x) : 0.0;
        std::vector<std::array<Vec2d, 2>> out;
        arc_chords(m_c.b, m_c.r, phi - Pi / 2, phi + Pi / 2, max_length, 4, out);
        const Vec2d n = m_c.r * Vec2d(-std::sin(phi), std::cos(phi));
        if (glm::length(ab) > 0) out.push_back({m_c.b + n, m_c.a + n});
        arc_chords(m_c.a, m_c.r, phi + Pi / 2, phi + 3 * Pi / 2, max_length, 4, out);
        if (glm::length(ab) > 0) out.push_back({m_c.a - n, m_c.b - n});
        return out;
    }

private:
    CapsuleGeometry<2> m_c;
};

class Capsule3 final : public Boundary3 {
public:
    explicit Capsule3(const Properties& props) : Boundary3(props, true), m_c(read_capsule<3>(props)) {
        if (m_role.moving()) props.error("velocity", "3D boundaries do not move (rigid motion is 2D only)");
    }
    double distance(const Vec3d& p) const override { return std::abs(m_c.signed_distance(p)); }
    BoundaryHit<3> closest(const Vec3d& p) const override { return m_c.closest(p); }
    bool has_inside() const override { return true; }
    bool inside3(const Vec3d& p) const override { return m_c.signed_distance(p) < 0; }
    std::pair<Vec3d, Vec3d> bounds() const override {
        return {glm::min(m_c.a, m_c.b) - m_c.r, glm::max(m_c.a, m_c.b) + m_c.r};
    }
    std::string description() const override { return fmt::format("capsule 3D (radius {:g})", m_c.r); }

private:
    CapsuleGeometry<3> m_c;
};

/// One plugin name for both dimensions, chosen by `dimension`.
using Capsule = ByDimension<Capsule2, Capsule3>;

}  // namespace
}  // namespace kelvin::wos::boundaries

KELVIN_BOUNDARY_PLUGIN(kelvin::wos::boundaries::Capsule, "capsule",
                       "Points within a radius of a segment (2D stadium, 3D capsule), exact distance.",
                       kelvin::param::integer("dimension", 2, "2 or 3"),
                       kelvin::param::point("a", kelvin::Vec3d(-0.25, 0, 0), "segment start"),
                       kelvin::param::point("b", kelvin::Vec3d(0.25, 0, 0), "segment end"),
                       kelvin::param::real("radius", 0.1, "radius"));
