#pragma once
// Elliptic discs (ShapeGeometry::Type::EllipticDiscs): the unit disk x^2 + y^2 <= 1 of the z = 0 plane under an
// affine map, c + x a + y b, with a and b (the images of the object's x and y axes) linearly independent but
// neither unit length nor orthogonal (Mitsuba's `disk` under a non-uniform scale or a shear in its plane). Geometry
// in double; shared by the renderer's Embree user geometry (scene.cpp) and the closest-point queries
// (closest_point.cpp).
#include <kelvin/render/shape.h>

#include <algorithm>
#include <cmath>
#include <optional>

namespace kelvin::ellipse {

struct View {
    Vec3d c, a, b, n;  ///< centre, the two semi-axis vectors (images of object x and y), the unit normal
    double gaa = 0, gab = 0, gbb = 0, inv_det = 0;  ///< the Gram matrix of (a, b) and 1 / its determinant
};

inline View of(const ShapeGeometry& g, std::size_t k) {
    View e;
    e.c = Vec3d(g.positions[k]);
    e.a = Vec3d(g.tangents[k]);
    e.b = Vec3d(g.bitangents[k]);
    e.n = glm::normalize(Vec3d(g.normals[k]));
    e.gaa = glm::dot(e.a, e.a);
    e.gab = glm::dot(e.a, e.b);
    e.gbb = glm::dot(e.b, e.b);
    const double det = e.gaa * e.gbb - e.gab * e.gab;
    e.inv_det = det > 0 ? 1.0 / det : 0.0;
    return e;
}

/// The largest distance from the centre of the ellipse with semi-axis vectors a and b (the larger singular value of
/// the map (x, y) -> x a + y b).
inline double extent(const Vec3d& a, const Vec3d& b) {
    const double p = glm::dot(a, a), q = glm::dot(b, b), r = glm::dot(a, b);
    return std::sqrt(0.5 * (p + q) + std::sqrt(0.25 * (p - q) * (p - q) + r * r));
}

/// Object coordinates (x, y) of a point of the plane (the component along the normal is ignored).
inline Vec2d local(const View& e, const Vec3d& p) {
    const Vec3d q = p - e.c;
    const double qa = glm::dot(q, e.a), qb = glm::dot(q, e.b);
    return {(e.gbb * qa - e.gab * qb) * e.inv_det, (e.gaa * qb - e.gab * qa) * e.inv_det};
}

/// The t in (tmin, tmax] where o + t d meets the ellipse, if any (d need not be unit length).
inline std::optional<double> intersect(const View& e, const Vec3d& o, const Vec3d& d, double tmin, double tmax) {
    const double dn = glm::dot(d, e.n);
    if (!(dn != 0)) return std::nullopt;  // parallel to the plane (or NaN)
    const double t = glm::dot(e.c - o, e.n) / dn;
    if (!(t > tmin && t <= tmax)) return std::nullopt;
    const Vec2d l = local(e, o + t * d);
    if (!(l.x * l.x + l.y * l.y <= 1)) return std::nullopt;
    return t;
}

/// The point of the ellipse (rim included) closest to p.
inline Vec3d closest_point(const View& e, const Vec3d& p) {
    const Vec2d l = local(e, p);
    if (l.x * l.x + l.y * l.y <= 1) return e.c + l.x * e.a + l.y * e.b;  // the foot of the perpendicular
    // On the rim c + cos(s) a + sin(s) b: minimise |cos(s) a + sin(s) b - q|^2 over s, from the best of 32 samples
    // by Newton's method on its derivative.
    const Vec3d q = p - e.c;
    auto dist2 = [&](double s) {
        const Vec3d r = std::cos(s) * e.a + std::sin(s) * e.b - q;
        return glm::dot(r, r);
    };
    double best = 0, best_d = dist2(0);
    for (int k = 1; k < 32; ++k) {
        const double s = 2 * Pi * k / 32, dd = dist2(s);
        if (dd < best_d) best = s, best_d = dd;
    }
    double s = best;
    for (int it = 0; it < 20; ++it) {
        const Vec3d r = std::cos(s) * e.a + std::sin(s) * e.b - q;
        const Vec3d r1 = -std::sin(s) * e.a + std::cos(s) * e.b, r2 = -std::cos(s) * e.a - std::sin(s) * e.b;
        const double f1 = glm::dot(r, r1), f2 = glm::dot(r1, r1) + glm::dot(r, r2);
        if (!(f2 > 0)) break;
        const double step = std::clamp(f1 / f2, -0.25, 0.25);
        s -= step;
        if (std::abs(step) < 1e-14) break;
    }
    if (!(dist2(s) <= best_d)) s = best;
    return e.c + std::cos(s) * e.a + std::sin(s) * e.b;
}

}  // namespace kelvin::ellipse
