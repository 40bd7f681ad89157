#pragma once
// Emitters. Area emitters are attached to a shape (<shape><emitter type="area"/></shape>); point, spot,
// constant and envmap emitters stand at the scene's root.
#include <kelvin/core/object.h>
#include <kelvin/render/interaction.h>

#include <cstdint>
#include <optional>

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
    Color3 weight{0.0}; ///< emitted radiance towards the reference point / pdf
};

/// An emitted ray (light tracing).
struct EmissionSample {
    Ray ray;
    Vec3d n{0.0};          ///< surface normal at the origin (zero for points)
    Color3 weight{0.0};    ///< Le * |cos| / (pdf_pos * pdf_dir)
    double pdf_pos = 0;    ///< area density of the origin (1 for delta positions)
    double pdf_dir = 0;    ///< solid-angle density of the direction
    bool delta_pos = false;
};

class Emitter : public Object {
public:
    virtual uint32_t flags() const = 0;
    /// Sample a point of the emitter as seen from `ref`.
    virtual std::optional<DirectSample> sample_direct(const Vec3d& ref, const Vec2d& u) const = 0;
    /// Solid-angle density, at `ref`, of sample_direct choosing the point `p` (with normal `n`); 0 for delta
    /// emitters. For infinite emitters `p` is ignored and `n` is unused; `d` is the unit direction ref -> p.
    virtual double pdf_direct(const Vec3d& ref, const Vec3d& p, const Vec3d& n, const Vec3d& d) const = 0;
    /// Radiance leaving the emitter at `p` (normal `n`) in unit direction `w` (pointing away from the emitter,
    /// towards the viewer). For infinite emitters: radiance arriving along -w from infinity.
    virtual Color3 eval(const Vec3d& p, const Vec3d& n, const Vec3d& w) const = 0;
    /// Sample an emitted ray with `u_pos` for the origin and `u_dir` for the direction.
    virtual std::optional<EmissionSample> sample_emission(const Vec2d& u_pos, const Vec2d& u_dir) const = 0;
    /// Total emitted power (watts, per channel); used to pick emitters in proportion to their power.
    virtual Color3 power() const = 0;

    /// Called by the scene before rendering: the shape an area emitter sits on, the scene's bounding sphere.
    virtual void set_shape(const Shape*) {}
    virtual void set_scene_bounds(const Vec3d& center, double radius) {}
};

}  // namespace kelvin
