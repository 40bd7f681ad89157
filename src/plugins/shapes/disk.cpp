// disk: Mitsuba's analytic unit disk, intersected by Embree's normal-oriented disc primitive.
//
// The disk of radius 1 centred on the origin in the z = 0 plane, normal +z, placed by `to_world`. Its texture
// coordinates are polar, as in Mitsuba: u = r (0 at the centre, 1 on the rim), v = phi / (2 pi) measured from
// the transformed +x axis. Embree's discs are round, so `to_world` must scale the disk's plane uniformly (any
// rotation, translation, mirror and scale along the normal are fine); an ellipse is refused with an error.
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

#include <cmath>

namespace kelvin {
namespace {

class Disk final : public Shape {
public:
    explicit Disk(const Properties& props) {
        const Transform t = props.get_transform("to_world");
        const Vec3d sx = t.apply_vector({1, 0, 0}), sy = t.apply_vector({0, 1, 0});
        const double lx = glm::length(sx), ly = glm::length(sy);
        if (!(lx > 0) || !(ly > 0) || !std::isfinite(lx * ly))
            props.error("to_world", "collapses the disk (zero or non-finite scale in its plane)");
        if (std::abs(lx - ly) > 1e-6 * lx || std::abs(glm::dot(sx, sy)) > 1e-6 * lx * ly)
            props.error("to_world", "a disk needs a uniform scale in its plane (an ellipse is not supported)");
        m_center = t.apply_point({0, 0, 0});
        m_radius = lx;
        m_tangent = sx / lx;
        // Normals transform with the inverse transpose (a mirror in the plane leaves +z as it is).
        m_normal = glm::normalize(t.apply_normal({0, 0, 1}));
        m_bitangent = glm::cross(m_normal, m_tangent);  // so that (tangent, bitangent, normal) is right-handed
        m_flip = props.get_bool("flip_normals");
        read_common(props);
    }
    ShapeGeometry geometry() const override {
        ShapeGeometry g;
        g.type = ShapeGeometry::Type::Discs;
        g.positions = {Vec3f(m_center)};
        g.radii = {float(m_radius)};
        g.normals = {Vec3f(m_normal)};
        g.tangents = {Vec3f(m_tangent)};
        g.flip_normals = m_flip;
        return g;
    }
    double surface_area() const override { return Pi * m_radius * m_radius; }
    PositionSample sample_position(const Vec2d& u) const override {
        const Vec2d d = warp::square_to_uniform_disk_concentric(u);
        PositionSample ps;
        ps.p = m_center + m_radius * (d.x * m_tangent + d.y * m_bitangent);
        ps.n = m_flip ? -m_normal : m_normal;
        const double phi = std::atan2(d.y, d.x);
        ps.uv = {glm::length(d), (phi < 0 ? phi + 2 * Pi : phi) / (2 * Pi)};
        ps.pdf = 1.0 / surface_area();
        return ps;
    }

private:
    Vec3d m_center, m_tangent, m_bitangent, m_normal;
    double m_radius;
    bool m_flip;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Disk, "shape", "disk", "Analytic unit disk in the z=0 plane, normal +z (Embree oriented disc).",
              kelvin::param::transform("to_world", "object-to-world transform (uniform scale in the disk's plane)"),
              kelvin::param::boolean("flip_normals", false, "the normal points along -z"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
