#pragma once
// Math types. GLM underneath; geometry in float, accumulators and parameters in double.
#include <glm/glm.hpp>

#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>

namespace kelvin {

using Vec2f = glm::vec2;
using Vec3f = glm::vec3;
using Vec4f = glm::vec4;
using Vec2d = glm::dvec2;
using Vec3d = glm::dvec3;
using Vec2i = glm::ivec2;
using Mat3d = glm::dmat3;
using Mat4d = glm::dmat4;

/// Linear RGB colour (double precision, as stored in Properties and accumulated in films).
using Color3 = glm::dvec3;

inline constexpr double Pi = std::numbers::pi;
inline constexpr double InvPi = 1.0 / std::numbers::pi;
inline constexpr double Inf = std::numeric_limits<double>::infinity();

/// An affine (or projective) transform with its inverse kept alongside.
struct Transform {
    Mat4d matrix{1.0};
    Mat4d inverse{1.0};

    Transform() = default;
    explicit Transform(const Mat4d& m);
    Transform(const Mat4d& m, const Mat4d& inv) : matrix(m), inverse(inv) {}

    Vec3d apply_point(const Vec3d& p) const;
    Vec3d apply_vector(const Vec3d& v) const;
    /// Normals transform with the inverse transpose.
    Vec3d apply_normal(const Vec3d& n) const;
    Transform operator*(const Transform& o) const { return {matrix * o.matrix, o.inverse * inverse}; }
    bool is_identity() const { return matrix == Mat4d(1.0); }
    /// Rotation and translation only (no scale, shear or mirror beyond a rotation's): the linear part is
    /// orthonormal to `tol`.
    bool is_rigid(double tol = 1e-6) const;

    static Transform translate(const Vec3d& t);
    static Transform scale(const Vec3d& s);
    /// Rotation by `angle_deg` degrees about `axis` (right-handed).
    static Transform rotate(const Vec3d& axis, double angle_deg);
    /// Camera-to-world: local +z looks from `origin` towards `target`, +y is `up` (Mitsuba's convention).
    static Transform look_at(const Vec3d& origin, const Vec3d& target, const Vec3d& up);
};

/// Luminance of linear sRGB/Rec.709 primaries.
inline double luminance(const Color3& c) { return 0.212671 * c.r + 0.715160 * c.g + 0.072169 * c.b; }

/// The largest |x|, |y| or |z| a scene point may have: geometry, sensors, lights and fluid boundaries alike. Ray and
/// closest-point queries run in single precision on Embree, which refuses coordinates beyond FLT_LARGE = 1.844e18; the
/// limit keeps an order of magnitude of margin (render/extent.h).
constexpr double MaxSceneCoordinate = 1e17;

/// True if every component of `p` is finite and within MaxSceneCoordinate (NaN fails).
inline bool within_scene_extent(const Vec3d& p) {
    return std::abs(p.x) <= MaxSceneCoordinate && std::abs(p.y) <= MaxSceneCoordinate &&
           std::abs(p.z) <= MaxSceneCoordinate;
}

}  // namespace kelvin
