#pragma once
// Open finite cylinders (ShapeGeometry::Type::Cylinders): the lateral surface of radius r around the axis from the
// base centre p0 along the unit vector ez, of length L, without caps (Mitsuba's `cylinder`). Geometry in double;
// shared by the renderer's Embree user geometry (scene.cpp) and the closest-point queries (closest_point.cpp).
#include <kelvin/render/shape.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <utility>

namespace kelvin::cylinder {

struct View {
    Vec3d p0, ex, ey, ez;  ///< base centre; ex, ey, ez a right-handed orthonormal frame, ez along the axis
    double r = 0, L = 0;
};

inline View of(const ShapeGeometry& g, std::size_t k) {
    View c;
    c.p0 = Vec3d(g.positions[k]);
    c.ez = glm::normalize(Vec3d(g.normals[k]));
    c.ex = Vec3d(g.tangents[k]);
    c.ex = glm::normalize(c.ex - c.ez * glm::dot(c.ez, c.ex));
    c.ey = glm::cross(c.ez, c.ex);
    c.r = g.radii[k];
    c.L = g.lengths[k];
    return c;
}

/// Axis-aligned bounds: the two end circles, each extending r sqrt(1 - ez_i^2) along axis i.
inline std::pair<Vec3d, Vec3d> bounds(const View& c) {
    const Vec3d e(c.r * std::sqrt(std::max(0.0, 1 - c.ez.x * c.ez.x)),
                  c.r * std::sqrt(std::max(0.0, 1 - c.ez.y * c.ez.y)),
                  c.r * std::sqrt(std::max(0.0, 1 - c.ez.z * c.ez.z)));
    const Vec3d p1 = c.p0 + c.L * c.ez;
    return {glm::min(c.p0, p1) - e, glm::max(c.p0, p1) + e};
}

/// The nearest t in (tmin, tmax] where o + t d meets the lateral surface, if any (d need not be unit length).
inline std::optional<double> intersect(const View& c, const Vec3d& o, const Vec3d& d, double tmin, double tmax) {
    const Vec3d q = o - c.p0;
    const double ox = glm::dot(q, c.ex), oy = glm::dot(q, c.ey), oz = glm::dot(q, c.ez);
    const double dx = glm::dot(d, c.ex), dy = glm::dot(d, c.ey), dz = glm::dot(d, c.ez);
    const double A = dx * dx + dy * dy, B = 2 * (dx * ox + dy * oy), C = ox * ox + oy * oy - c.r * c.r;
    if (!(A > 0)) return std::nullopt;  // parallel to the axis (or degenerate): never crosses the lateral surface
    const double disc = B * B - 4 * A * C;
    if (!(disc >= 0)) return std::nullopt;
    // Numerically stable roots (no cancellation between B and the square root).
    const double s = std::sqrt(disc), qq = -0.5 * (B + std::copysign(s, B));
    double t0 = qq / A, t1 = qq != 0 ? C / qq : t0;
    if (t0 > t1) std::swap(t0, t1);
    for (double t : {t0, t1}) {
        if (!(t > tmin && t <= tmax)) continue;
        const double z = oz + t * dz;
        if (z >= 0 && z <= c.L) return t;
    }
    return std::nullopt;
}

/// Local coordinates of a point: x, y across the axis, z along it.
inline Vec3d local(const View& c, const Vec3d& p) {
    const Vec3d q = p - c.p0;
    return {glm::dot(q, c.ex), glm::dot(q, c.ey), glm::dot(q, c.ez)};
}

/// Closest point of the lateral surface to `p`, and the outward radial normal there.
inline Vec3d closest_point(const View& c, const Vec3d& p, Vec3d& normal) {
    const Vec3d l = local(c, p);
    const double rho = std::hypot(l.x, l.y);
    const Vec3d radial = rho > 0 ? (l.x / rho) * c.ex + (l.y / rho) * c.ey : c.ex;  // on the axis: any direction
    normal = radial;
    return c.p0 + std::clamp(l.z, 0.0, c.L) * c.ez + c.r * radial;
}

}  // namespace kelvin::cylinder
