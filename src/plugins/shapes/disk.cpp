// disk: Mitsuba's analytic unit disk, mapped by `to_world`.
//
// The disk of radius 1 centred on the origin in the z = 0 plane, normal +z, placed by `to_world`. Its texture
// coordinates are polar in object space, as in Mitsuba: u = r (0 at the centre, 1 on the rim), v = phi / (2 pi)
// measured from the object's +x axis. Any affine `to_world` that keeps the disk flat is accepted: with a uniform
// scale in its plane the disk is round and intersected by Embree's normal-oriented disc primitive; a non-uniform
// scale or a shear in its plane makes it an ellipse (Mitsuba's elliptic disk), intersected as Embree user geometry
// in double (src/render/ellipse.h). The normal is the object's +z under the inverse transpose, the area pi |a x b|
// for the images a, b of the object's x and y axes, and a point sampled uniformly on the unit disk maps to a point
// uniform on the ellipse (the map is affine), so the positional pdf is 1 / area either way. The shading frame of an
// ellipse has dp/du as its tangent (Mitsuba's); a round disk keeps the orthonormal basis around its normal.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="disk">
//         <transform name="to_world"><scale value="0.3"/><rotate x="1" angle="90"/><translate y="2"/></transform>
//         <emitter type="area"><rgb name="radiance" value="20"/></emitter>
//     </shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/shape.h>
#include <kelvin/render/warp.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin {
namespace {

class Disk final : public Shape {
public:
    explicit Disk(const Properties& props) {
        const Transform t = props.get_transform("to_world");
        const Vec3d sx = t.apply_vector({1, 0, 0}), sy = t.apply_vector({0, 1, 0});
        const double lx = glm::length(sx), ly = glm::length(sy);
        const double area = Pi * glm::length(glm::cross(sx, sy));
        if (!(lx > 0) || !(ly > 0) || !std::isfinite(lx * ly) || !(area > 1e-12 * Pi * lx * ly))
            props.error("to_world", "collapses the disk (zero or non-finite scale in its plane)");
        m_center = t.apply_point({0, 0, 0});
        m_radius = lx;
        m_area = area;
        // Normals transform with the inverse transpose (a mirror in the plane leaves +z as it is).
        m_normal = glm::normalize(t.apply_normal({0, 0, 1}));
        m_elliptic = std::abs(lx - ly) > 1e-6 * lx || std::abs(glm::dot(sx, sy)) > 1e-6 * lx * ly;
        if (m_elliptic) {
            m_tangent = sx;  // the semi-axis vectors themselves: x sx + y sy for (x, y) on the unit disk
            m_bitangent = sy;
        } else {
            m_tangent = sx / lx;
            m_bitangent = glm::cross(m_normal, m_tangent);  // so that (tangent, bitangent, normal) is right-handed
            m_area = Pi * m_radius * m_radius;
        }
        m_flip = props.get_bool("flip_normals");
        read_common(props);
    }
    ShapeGeometry geometry() const override {
        ShapeGeometry g;
        g.type = m_elliptic ? ShapeGeometry::Type::EllipticDiscs : ShapeGeometry::Type::Discs;
        g.positions = {Vec3f(m_center)};
        g.radii = {float(m_elliptic ? ellipse_extent() : m_radius)};
        g.normals = {Vec3f(m_normal)};
        g.tangents = {Vec3f(m_tangent)};
        if (m_elliptic) g.bitangents = {Vec3f(m_bitangent)};
        g.flip_normals = m_flip;
        return g;
    }
    double surface_area() const override { return m_area; }
    PositionSample sample_position(const Vec2d& u) const override {
        const Vec2d d = warp::square_to_uniform_disk_concentric(u);
        PositionSample ps;
        ps.p = m_center + (m_elliptic ? 1.0 : m_radius) * (d.x * m_tangent + d.y * m_bitangent);
        ps.n = m_flip ? -m_normal : m_normal;
        const double phi = std::atan2(d.y, d.x);
        ps.uv = {glm::length(d), (phi < 0 ? phi + 2 * Pi : phi) / (2 * Pi)};
        ps.pdf = 1.0 / surface_area();
        return ps;
    }
    std::string to_string() const override {
        return m_elliptic ? fmt::format("{} (elliptic, area {:g})", Shape::to_string(), m_area) : Shape::to_string();
    }

private:
    // The larger singular value of (x, y) -> x a + y b: the farthest the rim gets from the centre.
    double ellipse_extent() const {
        const double p = glm::dot(m_tangent, m_tangent), q = glm::dot(m_bitangent, m_bitangent),
                     r = glm::dot(m_tangent, m_bitangent);
        return std::sqrt(0.5 * (p + q) + std::sqrt(0.25 * (p - q) * (p - q) + r * r));
    }

    Vec3d m_center, m_tangent, m_bitangent, m_normal;
    double m_radius, m_area;
    bool m_flip, m_elliptic;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::Disk, "shape", "disk",
    "Analytic unit disk in the z=0 plane, normal +z, mapped by to_world (round: Embree oriented disc; elliptic: user "
    "geometry).",
    kelvin::param::transform(
        "to_world",
        "object-to-world transform (any affine map; a non-uniform scale or shear in the plane makes an ellipse)"),
    kelvin::param::boolean("flip_normals", false, "the normal points along -z"),
    kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
    kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
