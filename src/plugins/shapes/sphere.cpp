// sphere: an analytic sphere, intersected by Embree's sphere primitive.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="sphere">
//         <point name="center" x="0" y="1" z="0"/>
//         <float name="radius" value="0.5"/>
//     </shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/shape.h>

#include <algorithm>
#include <cmath>

namespace kelvin {
namespace {

class Sphere final : public Shape {
public:
    explicit Sphere(const Properties& props) {
        Transform t = props.get_transform("to_world");
        double r = props.get_float("radius", 0.0, Inf);
        if (r <= 0) props.error("radius", "must be positive");
        // Embree spheres are round: the transform must scale all axes alike.
        Vec3d sx = t.apply_vector({1, 0, 0}), sy = t.apply_vector({0, 1, 0}), sz = t.apply_vector({0, 0, 1});
        double lx = glm::length(sx), ly = glm::length(sy), lz = glm::length(sz);
        if (std::abs(lx - ly) > 1e-6 * lx || std::abs(lx - lz) > 1e-6 * lx ||
            std::abs(glm::dot(sx, sy)) > 1e-6 * lx * ly || std::abs(glm::dot(sx, sz)) > 1e-6 * lx * lz ||
            std::abs(glm::dot(sy, sz)) > 1e-6 * ly * lz)
            props.error("to_world", "a sphere needs a similarity transform (no shear, no non-uniform scale)");
        m_center = t.apply_point(props.get_point("center"));
        m_radius = r * lx;
        m_flip = props.get_bool("flip_normals");
        read_common(props);
    }
    ShapeGeometry geometry() const override {
        ShapeGeometry g;
        g.type = ShapeGeometry::Type::Spheres;
        g.positions = {Vec3f(m_center)};
        g.radii = {float(m_radius)};
        g.flip_normals = m_flip;
        return g;
    }
    double surface_area() const override { return 4 * Pi * m_radius * m_radius; }
    PositionSample sample_position(const Vec2d& u) const override {
        double z = 1 - 2 * u.x, r = std::sqrt(std::max(0.0, 1 - z * z)), phi = 2 * Pi * u.y;
        Vec3d d(r * std::cos(phi), r * std::sin(phi), z);
        PositionSample ps;
        ps.p = m_center + m_radius * d;
        ps.n = m_flip ? -d : d;
        ps.uv = {phi / (2 * Pi), std::acos(std::clamp(z, -1.0, 1.0)) / Pi};
        ps.pdf = 1.0 / surface_area();
        return ps;
    }

private:
    Vec3d m_center;
    double m_radius;
    bool m_flip;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::Sphere, "shape", "sphere", "Analytic sphere (Embree sphere primitive).",
              kelvin::param::point("center", {0, 0, 0}, "centre in object space"),
              kelvin::param::real("radius", 1.0, "radius in object space"),
              kelvin::param::transform("to_world", "object-to-world similarity transform"),
              kelvin::param::boolean("flip_normals", false, "make normals point inwards"),
              kelvin::param::object("bsdf", "bsdf", "surface scattering (default: diffuse, reflectance 0.5)"),
              kelvin::param::object("emitter", "emitter", "makes the shape an area light"), KELVIN_SHAPE_MEDIA_PARAMS);
