#pragma once
#include <kelvin/core/math.h>

#include <cstdint>

namespace kelvin {

struct Ray {
    Vec3d o{0.0};
    Vec3d d{0.0, 0.0, 1.0};  ///< need not be normalised; t is measured in units of |d|
    double tmin = 0;
    double tmax = Inf;

    Vec3d at(double t) const { return o + t * d; }
};

/// A ray-surface hit.
struct SurfaceHit {
    double t = Inf;
    Vec3d p{0.0};
    Vec3d ng{0.0, 0.0, 1.0};  ///< geometric normal, unit length, as the shape orients it
    Vec2d uv{0.0};
    uint32_t shape = 0;  ///< the surface hit: Scene::shapes() index, or past them an instanced shape (Scene::shape_of)
    uint32_t prim = 0;   ///< primitive (triangle) index within the shape
};

}  // namespace kelvin
