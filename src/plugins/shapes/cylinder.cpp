// cylinder: Mitsuba's analytic open cylinder, intersected as Embree user geometry (src/render/cylinder.h).
//
// The lateral surface of radius `radius` around the segment from `p0` to `p1` (object space), without end caps,
// placed by `to_world`. Its normals point outwards (inwards with `flip_normals`): seen from inside, a one-sided BSDF
// is black, as in Mitsuba (use `twosided`). Texture coordinates as in Mitsuba: u = phi / (2 pi) around the axis,
// measured from the first tangent of the axis' orthonormal basis (Duff et al. 2017, as Mitsuba's Frame), and
// v = 0 at p0, 1 at p1; the shading frame's tangent is dp/du. The transform must keep the cross-section round
// (rotation, translation, uniform scale, and any scale along the axis); shear or an elliptic cross-section is refused
// with an error (Mitsuba only warns and then ignores it).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="cylinder">
//         <float name="radius" value="0.3"/>
//         <bsdf type="twosided"><bsdf type="diffuse"/></bsdf>
//     </shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/frame.h>
#include <kelvin/render/shape.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin {
namespace {

class Cylinder final : public Shape {
public:
    explicit Cylinder(const Properties& props) {
        const double radius = props.get_float("radius", 0.0, Inf);
        if (!(radius > 0)) props.error("radius", "must be positive");
        const Vec3d p0 = props.get_point("p0"), p1 = props.get_point("p1");
        const double length = glm::length(p1 - p0);
        if (!(length > 0) || !std::isfinite(length)) props.error("p1", "must differ from p0 (the axis has no length)");
        const Frame axis(glm::normalize(p1 - p0));
        const Transform t = props.get_transform("to_world");
        // Columns of the whole object-to-world map: the axis frame scaled by (radius, radius, length).
        const Vec3d cx = t.apply_vector(radius * axis.s), cy = t.apply_vector(radius * axis.t),
                    cz = t.apply_vector(length * axis.n);
        const double lx = glm::length(cx), ly = glm::length(cy), lz = glm::length(cz);
        if (!(lx > 0) || !(ly > 0) || !(lz > 0) || !std::isfinite(lx * ly * lz))
            props.error("to_world", "collapses the cylinder (zero or non-finite scale)");
        const double tol = 1e-6;
        if (std::abs(lx - ly) > tol * lx || std::abs(glm::dot(cx, cy)) > tol * lx * ly ||
            std::abs(glm::dot(cx, cz)) > tol * lx * lz || std::abs(glm::dot(cy, cz)) > tol * ly * lz)
            props.error("to_world",
                        "a cylinder needs a round cross-section: no shear and the same scale across its "
                        "axis (an elliptic cylinder is not supported)");
        m_p0 = t.apply_point(p0);
        m_radius = lx;
        m_length = lz;
        m_ex = cx / lx;
        m_ez = cz / lz;
        m_ey = glm::cross(m_ez, m_ex);  // right-handed even under a mirror (u then runs the other way than Mitsuba's)
        m_flip = props.get_bool("flip_normals");
        read_common(props);
    }
    ShapeGeometry geometry() const override {
        ShapeGeometry g;
        g.type = ShapeGeometry::Type::Cylinders;
        g.positions = {Vec3f(m_p0)};
        g.radii = {float(m_radius)};
        g.normals = {Vec3f(m_ez)};
        g.tangents = {Vec3f(m_ex)};
        g.lengths = {float(m_length)};
        g.flip_normals = m_flip;
        return g;
    }
    double surface_area() const override { return 2 * Pi * m_radius * m_length; }
    PositionSample sample_position(const Vec2d& u) const override {
        const double phi = 2 * Pi * u.y;
        const Vec3d radial = std::cos(phi) * m_ex + std::sin(phi) * m_ey;
        PositionSample ps;
        ps.p = m_p0 + m_radius * radial + u.x * m_length * m_ez;
        ps.n = m_flip ? -radial : radial;
        ps.uv = {u.y, u.x};
        ps.pdf = 1.0 / surface_area();
        return ps;
    }
    std::string to_string() const override {
        return fmt::format("cylinder (radius {:g}, length {:g})", m_radius, m_length);
    }

private:
    Vec3d m_p0, m_ex, m_ey, m_ez;
    double m_radius, m_length;
    bool m_flip;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Cylinder, "shape", "cylinder",
              "Analytic open cylinder (no caps) around the axis p0-p1 (Mitsuba's cylinder; Embree user geometry).",
              kelvin::param::point("p0", {0, 0, 0}, "start of the axis (object space)"),
              kelvin::param::point("p1", {0, 0, 1}, "end of the axis (object space)"),
              kelvin::param::real("radius", 1.0, "radius (object space)"),
              kelvin::param::transform("to_world", "object-to-world transform (round cross-section)"),
              kelvin::param::boolean("flip_normals", false, "normals point inwards"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
