#pragma once
// A surface interaction: a hit with its shading frame and the direction it was reached from.
#include <kelvin/render/frame.h>
#include <kelvin/render/ray.h>

#include <cmath>

namespace kelvin {

class Shape;

struct SurfaceInteraction {
    Vec3d p{0.0};
    Vec3d ng{0, 0, 1};  ///< geometric normal (unit, as the shape orients it)
    Vec3d ns{0, 0, 1};  ///< shading normal (interpolated vertex normal, or ng)
    Vec2d uv{0.0};
    double t = Inf;
    Frame frame;        ///< shading frame around ns
    Vec3d wi{0, 0, 1};  ///< direction towards the previous vertex, in the shading frame
    const Shape* shape = nullptr;
    uint32_t shape_index = 0;
    uint32_t prim = 0;
    Vec2d bary{0.0};   ///< triangles: barycentric weights of the primitive's second and third vertices
    Vec3d dp_du{0.0};  ///< world-space tangent dp/du (Mitsuba's; meshes: from the uvs, else the normal's basis)
    Vec3d dp_dv{0.0};  ///< world-space tangent dp/dv (likewise)

    Vec3d to_local(const Vec3d& v) const { return frame.to_local(v); }
    Vec3d to_world(const Vec3d& v) const { return frame.to_world(v); }
    /// A ray leaving the surface in world direction `d`, offset along the geometric normal to avoid
    /// self-intersection.
    Ray spawn(const Vec3d& d) const;
    /// A ray from here to `target`, stopping just short of it (shadow rays).
    Ray spawn_to(const Vec3d& target) const;
};

/// Veach's correction for shading normals in adjoint (importance) transport: the factor that turns the BSDF
/// evaluated with the shading normal into the adjoint BSDF, |wi.ns| |wo.ng| / (|wi.ng| |wo.ns|) for local
/// directions wi, wo (Veach 1997, Eq. 5.19). 1 where ns == ng; 0 for directions grazing the geometry.
inline double shading_correction(const SurfaceInteraction& si, const Vec3d& wi, const Vec3d& wo) {
    const double ng_wi = std::abs(glm::dot(si.to_world(wi), si.ng)), ng_wo = std::abs(glm::dot(si.to_world(wo), si.ng));
    const double ns_wi = std::abs(wi.z), ns_wo = std::abs(wo.z);
    if (ng_wi == 0 || ns_wo == 0) return 0.0;
    return (ns_wi * ng_wo) / (ng_wi * ns_wo);
}

}  // namespace kelvin
