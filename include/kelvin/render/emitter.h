#pragma once
// Emitters. Area emitters are attached to a shape (<shape><emitter type="area"/></shape>); point, spot,
// constant and envmap emitters stand at the scene's root.
#include <kelvin/core/object.h>
#include <kelvin/render/diff_types.h>
#include <kelvin/render/interaction.h>

#include <cstdint>
#include <optional>
#include <utility>

namespace kelvin {

class Shape;

namespace EmitterFlags {
enum : uint32_t {
    None = 0,
    DeltaPosition = 1u << 0,   ///< a point: cannot be hit by a ray
    DeltaDirection = 1u << 1,  ///< a direction: cannot be hit by a ray
    Infinite = 1u << 2,        ///< at infinity: seen by rays that escape the scene
    Surface = 1u << 3,         ///< attached to a shape: seen by rays that hit it
    Delta = DeltaPosition | DeltaDirection,
};
}

/// A point on an emitter chosen as seen from a reference point (next-event estimation).
struct DirectSample {
    Vec3d p{0.0};       ///< point on the emitter (for infinite emitters: far away along d)
    Vec3d n{0.0};       ///< emitter normal at p (zero for points and infinite emitters)
    Vec3d d{0, 0, 1};   ///< unit direction from the reference point to p
    double dist = Inf;  ///< distance from the reference point to p (Inf for infinite emitters)
    double pdf = 0;     ///< solid-angle density at the reference point (1 for delta emitters)
    bool delta = false;
    Color3 weight{0.0};  ///< emitted radiance towards the reference point / pdf
};

/// An emitted ray (light tracing).
struct EmissionSample {
    Ray ray;
    Vec3d n{0.0};        ///< surface normal at the origin (zero for points)
    Vec2d uv{0.0};       ///< surface uv of the origin (area emitters: where a textured radiance is read)
    Color3 weight{0.0};  ///< Le * |cos| / (pdf_pos * pdf_dir)
    double pdf_pos = 0;  ///< area density of the origin (1 for delta positions)
    double pdf_dir = 0;  ///< solid-angle density of the direction
    bool delta_pos = false;

    /// The ray to trace. `ray` starts exactly on the emitter; from a surface emitter (n != 0) it is offset along
    /// n as every ray leaving a surface is (SurfaceInteraction::spawn). Tracing `ray` itself from a curved
    /// emitter hits the emitter's own surface at t ~ 0 about half of the time (the origin rounds to either side
    /// of it), which ends the light path on the emitter's back face.
    Ray spawn_ray() const {
        if (n == Vec3d(0.0)) return ray;
        SurfaceInteraction origin;
        origin.p = ray.o;
        origin.ng = n;
        Ray r = origin.spawn(ray.d);
        r.tmax = ray.tmax;
        return r;
    }
};

/// Where a direction from a lit point reaches an emitter: what pdf_direct() reads (the role of Mitsuba 3's
/// DirectionSample and pbrt-v4's LightSampleContext). Emitters at infinity read `d` only.
struct DirectQuery {
    Vec3d ref{0.0};  ///< the lit point
    Vec3d p{0.0};    ///< the point of the emitter the direction reaches
    Vec3d n{0.0};    ///< the emitter's normal at p
    Vec3d d{0.0};    ///< unit direction from ref towards p
};

/// Where eval_diff() reads an emitter, in a number type T (differentiable path evaluation).
template <class T>
struct DiffEmitterQuery {
    const kernels::V3<T>& p;                    ///< the point on the emitter
    const kernels::V3<T>& n;                    ///< its (geometric) normal
    const kernels::V3<T>& d;                    ///< unit direction of the ray arriving at p (eval()'s w is -d)
    const DiffTextures<T>* textures = nullptr;  ///< the textures at p (null: a textured radiance is not differentiable)
};

/// What sample_direct_diff() gives, in a number type T.
template <class T>
struct DiffDirectSample {
    kernels::V3<T> d;              ///< unit direction from the reference point towards the light
    T dist;                        ///< distance to the light (infinite for a direction)
    kernels::C3<T> weight;         ///< what sample_direct() weighs the sample with (radiance / pdf)
    unsigned long long piece = 0;  ///< a piecewise constant texture's piece (DiffTextureQuery::piece; 0: none)
};

class Emitter : public Object {
public:
    virtual uint32_t flags() const = 0;
    /// Sample a point of the emitter as seen from `ref`.
    virtual std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d& u) const = 0;
    /// Solid-angle density, at q.ref, of sample_direct choosing the point q.p (with normal q.n) in direction q.d;
    /// 0 for delta emitters. Infinite emitters read q.d only.
    virtual double pdf_direct(const DirectQuery& q) const = 0;
    /// True where sample_direct() picks a surface point with a density other than its origin density in
    /// sample_emission() (pdf_emission().first) converted to solid angle: an area light on a sphere, which samples the
    /// cone the sphere subtends. Bidirectional MIS then weighs next-event estimation by pdf_direct().
    virtual bool direct_differs_from_emission() const { return false; }
    /// Radiance leaving the emitter at `p` (normal `n`, surface coordinates `uv`) in unit direction `w` (pointing
    /// away from the emitter, towards the viewer). For infinite emitters: radiance arriving along -w from infinity
    /// (`n` and `uv` unused). An area emitter with a textured radiance reads its texture at `uv`.
    virtual Color3 eval(const Vec3d& p, const Vec3d& n, const Vec2d& uv, const Vec3d& w) const = 0;
    /// Whether eval() varies over the surface (a textured area emitter).
    virtual bool spatially_varying() const { return false; }
    /// Sample an emitted ray with `u_pos` for the origin and `u_dir` for the direction.
    virtual std::optional<EmissionSample> sample_emission(const Vec2d& u_pos, const Vec2d& u_dir) const = 0;
    /// Densities with which sample_emission produces origin `p` (normal `n`; area density, 1 for delta
    /// positions; for infinite emitters the density on the scene-tangent disk) and unit direction `d`
    /// (solid angle). Bidirectional MIS needs them. Default: not generated by emission sampling (0, 0), which
    /// bidirectional integrators reject with a clear error.
    virtual std::pair<double, double> pdf_emission(const Vec3d& p, const Vec3d& n, const Vec3d& d) const {
        return {0.0, 0.0};
    }
    /// Total emitted power (watts, per channel); used to pick emitters in proportion to their power.
    virtual Color3 power() const = 0;

    /// Differentiable evaluation (H2MC: mlt/path_derivatives.h). eval() in a number type T: the radiance leaving the
    /// emitter at q.p (normal q.n) back along the arriving ray q.d, functions of a path's coordinates; a textured
    /// radiance is asked of the path (q.textures). False: not differentiable (the default). Plugins implement the three
    /// through one template, DifferentiableEmitter (render/differentiable.h).
    virtual bool eval_diff(const DiffEmitterQuery<double>& q, kernels::C3<double>& out) const { return false; }
    virtual bool eval_diff(const DiffEmitterQuery<DiffGradient>& q, kernels::C3<DiffGradient>& out) const {
        return false;
    }
    virtual bool eval_diff(const DiffEmitterQuery<DiffHessian>& q, kernels::C3<DiffHessian>& out) const {
        return false;
    }
    /// sample_direct() in a number type T for emitters whose sample does not depend on the light-sample coordinates
    /// (a delta position or direction: point, spot, directional): the unit direction from `ref` towards the light and
    /// the weight (intensity / dist^2, irradiance), functions of `ref`. False: not differentiable (the default), or no
    /// sample where sample_direct() gives none.
    virtual bool sample_direct_diff(const kernels::V3<double>& ref, DiffDirectSample<double>& out) const {
        return false;
    }
    virtual bool sample_direct_diff(const kernels::V3<DiffGradient>& ref, DiffDirectSample<DiffGradient>& out) const {
        return false;
    }
    virtual bool sample_direct_diff(const kernels::V3<DiffHessian>& ref, DiffDirectSample<DiffHessian>& out) const {
        return false;
    }

    /// Called by the scene before rendering: the shape an area emitter sits on, the scene's bounding sphere.
    virtual void set_shape(const Shape*) {}
    virtual void set_scene_bounds(const Vec3d& center, double radius) {}
};

}  // namespace kelvin
