// sphere: an analytic sphere, intersected by Embree's sphere primitive. As an area light seen from outside, next-event
// estimation samples the cone of directions it subtends (sample_direction), not its area.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <shape type="sphere">
//         <point name="center" x="0" y="1" z="0"/>
//         <float name="radius" value="0.5"/>
//     </shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/frame.h>
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
    /// Seen from outside: uniform in the cone of directions the sphere subtends (cos theta uniform in
    /// [cos theta_max, 1]), the point being where the direction first meets the sphere. From inside (or on) the
    /// sphere: the uniform point converted to solid angle (Shape's default), every point being visible there.
    ShapeDirectSample sample_direction(const Vec3d& ref, const Vec2d& u) const override {
        const Cone c = cone(ref);
        if (!c.outside) return Shape::sample_direction(ref, u);
        // 1 - cos theta uniform in [0, 1 - cos theta_max]; sin^2 theta from it without cancellation.
        const double omc = u.x * c.one_minus_cos_max, cos_t = 1 - omc, sin2_t = omc * (2 - omc);
        const double phi = 2 * Pi * u.y, cos_p = std::cos(phi), sin_p = std::sin(phi);
        // The angle alpha at the centre between the directions to ref and to the point: by the law of sines in the
        // triangle (ref, centre, point) the angle at the point is pi - asin(sin theta / sin theta_max) on the near
        // side, so alpha = asin(sin theta / sin theta_max) - theta.
        const double ratio2 = std::min(1.0, sin2_t / c.sin2_max);
        const double cos_a = sin2_t / c.sin_max + cos_t * std::sqrt(std::max(0.0, 1 - ratio2));
        const double sin_a = std::sqrt(std::max(0.0, 1 - cos_a * cos_a));
        // Frame around w, the direction from ref to the centre; the point's outward normal leans from -w towards the
        // sampled direction's side (cos phi s + sin phi t).
        const Frame f(c.w);
        const Vec3d out = -cos_a * c.w + sin_a * (cos_p * f.s + sin_p * f.t);
        ShapeDirectSample ds;
        ds.p = m_center + m_radius * out;
        ds.n = m_flip ? -out : out;
        ds.uv = uv_of(out);
        ds.pdf = 1 / (2 * Pi * c.one_minus_cos_max);
        return ds;
    }
    /// The density of sample_direction(): from outside, uniform over the cone for points on the near side (those a
    /// ray from ref meets first; 0 on the far side); from inside, the area density converted.
    double pdf_direction(const DirectQuery& q) const override {
        const Cone c = cone(q.ref);
        if (!c.outside) return Shape::pdf_direction(q);
        // The near side: the outward normal faces ref (within rounding of the silhouette, where both sides meet).
        if (glm::dot(q.p - m_center, q.d) > 1e-6 * m_radius) return 0.0;
        return 1 / (2 * Pi * c.one_minus_cos_max);
    }
    bool samples_solid_angle() const override { return true; }

private:
    // The cone the sphere subtends from a reference point: unit axis w towards the centre, sin^2 and sin of its
    // half-angle theta_max, and 1 - cos theta_max computed as sin^2 / (1 + cos), accurate for tiny angles (a
    // distant sphere) where 1 - cos would cancel to nothing.
    struct Cone {
        bool outside = false;
        Vec3d w{0.0};
        double sin2_max = 0, sin_max = 0, one_minus_cos_max = 0;
    };
    Cone cone(const Vec3d& ref) const {
        Cone c;
        const Vec3d to_c = m_center - ref;
        const double d2 = glm::dot(to_c, to_c), r2 = m_radius * m_radius;
        if (!(d2 > r2)) return c;
        const double d = std::sqrt(d2);
        c.sin2_max = r2 / d2;
        c.sin_max = m_radius / d;
        c.one_minus_cos_max = c.sin2_max / (1 + std::sqrt(std::max(0.0, 1 - c.sin2_max)));
        if (!(c.one_minus_cos_max > 0) || !(c.sin_max > 0)) return c;  // too far for doubles: area sampling
        c.w = to_c / d;
        c.outside = true;
        return c;
    }
    // Mitsuba's parameterisation in world axes, as the scene gives it at a hit (u = phi / 2 pi in [0, 1)).
    static Vec2d uv_of(const Vec3d& d) {
        double u = std::atan2(d.y, d.x) / (2 * Pi);
        if (u < 0) u += 1;
        return {u, std::acos(std::clamp(d.z, -1.0, 1.0)) / Pi};
    }

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
