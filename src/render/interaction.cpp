#include <kelvin/render/interaction.h>

#include <algorithm>
#include <cmath>

namespace kelvin {

// Offset proportional to the coordinates' magnitude: float geometry has a relative error of about 1e-7.
static double offset_scale(const Vec3d& p) {
    return 1e-5 * (1.0 + std::max({std::abs(p.x), std::abs(p.y), std::abs(p.z)}));
}

Ray SurfaceInteraction::spawn(const Vec3d& d) const {
    const double eps = offset_scale(p);
    Vec3d o = p + (glm::dot(d, ng) >= 0 ? eps : -eps) * ng;
    return Ray{o, d, 0.0, Inf};
}

Ray SurfaceInteraction::spawn_to(const Vec3d& target) const {
    const double eps = offset_scale(p);
    Vec3d d = target - p;
    Vec3d o = p + (glm::dot(d, ng) >= 0 ? eps : -eps) * ng;
    d = target - o;
    return Ray{o, d, 0.0, 1.0 - 1e-4};  // t in units of |d|: stop just short of the target
}

}  // namespace kelvin
