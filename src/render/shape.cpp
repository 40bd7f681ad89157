#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>
#include <kelvin/render/shape.h>

#include <cmath>

namespace kelvin {

void Shape::read_common(const Properties& props) {
    m_bsdf = object_or_default<Bsdf>(props, "bsdf", "bsdf", "diffuse");  // Mitsuba's default: diffuse, 0.5
    m_emitter = props.get_object_as<Emitter>("emitter");
    // Only by name (an unnamed <medium> would otherwise match both; it is left unused, which is an error).
    if (props.has("interior")) {
        m_interior = props.get_object_as<Medium>("interior");
        m_interior_loc = props.location_of("interior");
    }
    if (props.has("exterior")) m_exterior = props.get_object_as<Medium>("exterior");
}

ShapeDirectSample Shape::sample_direction(const Vec3d& ref, const Vec2d& u) const {
    // The uniform point converted to solid angle, pdf_A d^2 / |cos|, in the operations AreaEmitter::sample_direct
    // has always used (images of scenes lit by these shapes stay the same bit for bit).
    const PositionSample ps = sample_position(u);
    ShapeDirectSample s;
    s.p = ps.p;
    s.n = ps.n;
    s.uv = ps.uv;
    Vec3d d = ps.p - ref;
    const double dist2 = glm::dot(d, d);
    if (!(dist2 > 0)) return s;
    d /= std::sqrt(dist2);
    const double cos_e = std::abs(glm::dot(ps.n, d));
    s.pdf = ps.pdf * dist2 / cos_e;
    return s;
}

double Shape::pdf_direction(const DirectQuery& q) const {
    const double cos_e = std::abs(glm::dot(q.n, q.d));
    const Vec3d v = q.p - q.ref;
    return glm::dot(v, v) / (cos_e * surface_area());
}

void curve_angle_reference(const Vec3d& t, Vec3d& v_rot, Vec3d& v_rad) {
    const Vec3d guide(0, 0, 1);
    const Vec3d p = guide - t * glm::dot(t, guide);
    const double l = glm::length(p);
    v_rot = l > 1e-12 ? p / l : Vec3d(0, 1, 0);
    v_rad = glm::cross(v_rot, t);
}

void curve_point(const ShapeGeometry& g, std::size_t segment, double u, Vec3d& c, Vec3d& dc, double& r) {
    const uint32_t i = g.indices[segment];
    if (g.type == ShapeGeometry::Type::LinearCurves) {
        const Vec3d p0(g.positions[i]), p1(g.positions[i + 1]);
        c = (1 - u) * p0 + u * p1;
        dc = p1 - p0;
        r = (1 - u) * double(g.radii[i]) + u * double(g.radii[i + 1]);
        return;
    }
    // Uniform cubic B-spline basis and its derivative.
    const double v = 1 - u, u2 = u * u, u3 = u2 * u;
    const double b[4] = {v * v * v / 6, (3 * u3 - 6 * u2 + 4) / 6, (-3 * u3 + 3 * u2 + 3 * u + 1) / 6, u3 / 6};
    const double db[4] = {-v * v / 2, (3 * u2 - 4 * u) / 2, (-3 * u2 + 2 * u + 1) / 2, u2 / 2};
    c = dc = Vec3d(0.0);
    r = 0;
    for (int k = 0; k < 4; ++k) {
        const Vec3d p(g.positions[i + k]);
        c += b[k] * p;
        dc += db[k] * p;
        r += b[k] * double(g.radii[i + k]);
    }
}

}  // namespace kelvin
