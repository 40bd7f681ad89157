#pragma once
// Orthonormal frames for local shading coordinates (z = normal).
#include <kelvin/core/math.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

struct Frame {
    Vec3d s{1, 0, 0}, t{0, 1, 0}, n{0, 0, 1};

    Frame() = default;
    /// Frame around a unit normal (Duff et al. 2017, "Building an orthonormal basis, revisited").
    explicit Frame(const Vec3d& normal) : n(normal) {
        double sign = std::copysign(1.0, n.z), a = -1.0 / (sign + n.z), b = n.x * n.y * a;
        s = Vec3d(1 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        t = Vec3d(b, sign + n.y * n.y * a, -n.y);
    }
    Vec3d to_local(const Vec3d& v) const { return {glm::dot(v, s), glm::dot(v, t), glm::dot(v, n)}; }
    Vec3d to_world(const Vec3d& v) const { return s * v.x + t * v.y + n * v.z; }

    static double cos_theta(const Vec3d& v) { return v.z; }
    static double cos2_theta(const Vec3d& v) { return v.z * v.z; }
    static double sin2_theta(const Vec3d& v) { return std::max(0.0, 1.0 - v.z * v.z); }
    static double tan2_theta(const Vec3d& v) { return sin2_theta(v) / cos2_theta(v); }
};

}  // namespace kelvin
