#pragma once
// The coordinates a scene may use.
//
// Embree 3 traces single-precision rays and refuses (an assertion in RayK::valid(), kernels/common/ray.h: SIGABRT in
// builds that keep assertions) any ray whose origin or direction has a component beyond FLT_LARGE = 1.844e18, or
// whose tnear/tfar is NaN; vertices beyond it are dropped from the BVH. Rays start on surfaces, at the sensor and at
// emitters, so the scene's own coordinates are limited to MaxSceneCoordinate, an order of magnitude inside Embree's
// bound: a point on a surface plus a ray offset, or an infinite emitter's disk around the scene, stays traceable.
// Shapes (after their transforms, instances included), the sensor and positional emitters are checked when the scene
// is built (bad input, naming the element); every ray is checked again before it reaches Embree (scene.cpp), so a
// ray made invalid by arithmetic (a product that overflows) is counted instead of aborting the process.
#include <kelvin/core/error.h>
#include <kelvin/core/math.h>

#include <cmath>
#include <string_view>

#include <fmt/format.h>

namespace kelvin {

// MaxSceneCoordinate and within_scene_extent: core/math.h (fluid boundaries keep the same limit).
/// Embree's bound on ray origins and directions (FLT_LARGE in Embree's kernels/common/math/constants.h).
constexpr float EmbreeLargestCoordinate = 1.844e18f;

/// Throws InputError(loc, "<what> ...") unless the box [lo, hi] lies within the scene extent.
inline void check_scene_extent(const Vec3d& lo, const Vec3d& hi, std::string_view what, const SourceLoc& loc) {
    if (within_scene_extent(lo) && within_scene_extent(hi)) return;
    throw InputError(loc, fmt::format("{} extends to ({:g}, {:g}, {:g}) .. ({:g}, {:g}, {:g}), beyond the {:g} that "
                                      "scene coordinates may reach (the ray tracer's limit, with margin); scale "
                                      "the scene down",
                                      what, lo.x, lo.y, lo.z, hi.x, hi.y, hi.z, MaxSceneCoordinate));
}

/// Throws InputError(loc, "<what> ...") unless the point `p` lies within the scene extent.
inline void check_scene_point(const Vec3d& p, std::string_view what, const SourceLoc& loc) {
    if (within_scene_extent(p)) return;
    throw InputError(loc, fmt::format("{} is at ({:g}, {:g}, {:g}), beyond the {:g} that scene coordinates may reach "
                                      "(the ray tracer's limit, with margin); scale the scene down",
                                      what, p.x, p.y, p.z, MaxSceneCoordinate));
}

}  // namespace kelvin
