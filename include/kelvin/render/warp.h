#pragma once
// Sample warps from [0,1)^2 to common domains, each with its density (w.r.t. solid angle or area).
#include <kelvin/core/math.h>

#include <algorithm>
#include <cmath>

namespace kelvin::warp {

/// Concentric mapping to the unit disk (Shirley and Chiu 1997).
inline Vec2d square_to_uniform_disk_concentric(const Vec2d& u) {
    double x = 2 * u.x - 1, y = 2 * u.y - 1;
    if (x == 0 && y == 0) return {0, 0};
    double r, phi;
    if (std::abs(x) > std::abs(y)) {
        r = x;
        phi = (Pi / 4) * (y / x);
    } else {
        r = y;
        phi = (Pi / 2) - (Pi / 4) * (x / y);
    }
    return {r * std::cos(phi), r * std::sin(phi)};
}

inline Vec3d square_to_cosine_hemisphere(const Vec2d& u) {
    Vec2d d = square_to_uniform_disk_concentric(u);
    double z = std::sqrt(std::max(0.0, 1 - d.x * d.x - d.y * d.y));
    return {d.x, d.y, z};
}
inline double square_to_cosine_hemisphere_pdf(const Vec3d& v) { return v.z > 0 ? v.z * InvPi : 0.0; }

inline Vec3d square_to_uniform_sphere(const Vec2d& u) {
    double z = 1 - 2 * u.x, r = std::sqrt(std::max(0.0, 1 - z * z)), phi = 2 * Pi * u.y;
    return {r * std::cos(phi), r * std::sin(phi), z};
}
inline double square_to_uniform_sphere_pdf() { return 1.0 / (4 * Pi); }

inline Vec3d square_to_uniform_hemisphere(const Vec2d& u) {
    double z = u.x, r = std::sqrt(std::max(0.0, 1 - z * z)), phi = 2 * Pi * u.y;
    return {r * std::cos(phi), r * std::sin(phi), z};
}
inline double square_to_uniform_hemisphere_pdf(const Vec3d& v) { return v.z >= 0 ? 1.0 / (2 * Pi) : 0.0; }

/// Uniform direction inside a cone of half-angle acos(cos_max) around +z.
inline Vec3d square_to_uniform_cone(const Vec2d& u, double cos_max) {
    double z = 1 - u.x * (1 - cos_max), r = std::sqrt(std::max(0.0, 1 - z * z)), phi = 2 * Pi * u.y;
    return {r * std::cos(phi), r * std::sin(phi), z};
}
inline double square_to_uniform_cone_pdf(double cos_max) { return 1.0 / (2 * Pi * (1 - cos_max)); }

/// Uniform barycentrics on a triangle (returns (b1, b2); b0 = 1 - b1 - b2).
inline Vec2d square_to_uniform_triangle(const Vec2d& u) {
    double su = std::sqrt(u.x);
    return {u.y * su, 1 - su};
}

}  // namespace kelvin::warp
