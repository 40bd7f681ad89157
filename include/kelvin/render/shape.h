#pragma once
// Shapes describe their geometry to the scene, which hands it to Embree. Shapes never see Embree types, so
// a plugin author adding a shape needs no Embree headers.
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/ply.h>

#include <cstdint>
#include <memory>
#include <vector>

namespace kelvin {

class Medium;

/// Geometry a shape intersects itself (ShapeGeometry::Type::User): the scene hands it to Embree as user geometry
/// with one primitive per `primitive_count()`, and calls back into it for bounds, ray tests and the shading at a hit.
/// All in the geometry's own space (the world, or an instanced group's space). Not in closest-point queries.
class UserGeometry {
public:
    virtual ~UserGeometry() = default;
    virtual std::size_t primitive_count() const = 0;
    /// Axis-aligned bounds of primitive `prim` (conservative).
    virtual std::pair<Vec3d, Vec3d> bounds(std::size_t prim) const = 0;
    /// The nearest t in (tmin, tmax] where o + t d meets primitive `prim`, with the geometric normal there (any
    /// length, facing the surface's outside); false for none. d need not be unit length.
    virtual bool intersect(std::size_t prim, const Vec3d& o, const Vec3d& d, double tmin, double tmax, double& t,
                           Vec3d& ng) const = 0;
    /// The unit shading normal at the hit point p of primitive `prim` whose unit geometric normal is ng (default ng).
    virtual Vec3d shading_normal(std::size_t prim, const Vec3d& p, const Vec3d& ng) const { return ng; }
    /// The surface's parameterisation at the hit point p of primitive `prim`: its uv and the tangents dp/du, dp/dv
    /// (the shading frame's tangent is then dp/du). False (the default): none (uv 0, tangents from the normal).
    virtual bool parameterisation(std::size_t prim, const Vec3d& p, Vec2d& uv, Vec3d& dp_du, Vec3d& dp_dv) const {
        return false;
    }
};

/// World-space geometry in Embree-ready layout (float positions, 32-bit indices).
struct ShapeGeometry {
    enum class Type { Triangles, Spheres, Discs, Cylinders, LinearCurves, BSplineCurves, EllipticDiscs, User };
    Type type = Type::Triangles;
    std::vector<Vec3f> positions;   ///< triangle vertices, sphere / disc centres, cylinder base centres, or
                                    ///< curve control points
    std::vector<uint32_t> indices;  ///< 3 per triangle (counter-clockwise = front, normal by right hand); curves:
                                    ///< one per segment, its first control point (2 points per linear segment,
                                    ///< 4 per uniform cubic B-spline segment)
    std::vector<float> radii;       ///< spheres, discs and cylinders: one per centre; curves: one per control point;
                                    ///< elliptic discs: the largest distance of the rim from the centre
    std::vector<Vec3f>
        normals;  ///< triangles: optional per-vertex shading normals (same count as positions);
                  ///< discs and elliptic discs: the unit normal of each (required); cylinders: the unit axis
    std::vector<Vec3f> tangents;       ///< discs and cylinders: a unit vector perpendicular to the normal / axis, where
                                       ///< the polar angle of uv is 0; elliptic discs: the image of the object's x
                                       ///< axis (the semi-axis vector where that angle is 0, not unit length)
    std::vector<Vec3f> bitangents;     ///< elliptic discs: the image of the object's y axis (the disc is
                                       ///< {centre + x tangent + y bitangent : x^2 + y^2 <= 1})
    std::vector<float> lengths;        ///< cylinders: the length along the axis (open ends: no caps)
    std::vector<Vec2f> uvs;            ///< triangles: optional per-vertex texture coordinates; curves: per segment,
                                       ///< v (along the curve) at its start and the v it spans
    std::vector<uint8_t> curve_flags;  ///< linear curves, per segment: bit 0 set when a segment of the same curve
                                       ///< comes before it, bit 1 when one follows (joints are not capped inside)
    std::shared_ptr<const UserGeometry> user;  ///< user geometry: the shape's own intersection code
    bool flip_normals = false;
};

/// A curve segment of `g` (LinearCurves or BSplineCurves) at its parameter u in [0, 1]: the centre line's point
/// `c`, its derivative `dc` = dc/du and the radius `r` (the control points' radii blended as the points are).
void curve_point(const ShapeGeometry& g, std::size_t segment, double u, Vec3d& c, Vec3d& dc, double& r);
/// Mitsuba's reference directions around a curve of unit direction `t`, from which the angle of its v coordinate is
/// measured: v_rot, the projection of +z perpendicular to t (+y where t is along z), and v_rad = v_rot x t, where the
/// angle is 0; the angle grows from v_rad towards v_rot.
void curve_angle_reference(const Vec3d& t, Vec3d& v_rot, Vec3d& v_rad);

/// A point chosen on a shape's surface with density `pdf` per unit area.
struct PositionSample {
    Vec3d p{0.0};
    Vec3d n{0, 0, 1};
    Vec2d uv{0.0};
    double pdf = 0;
};

/// A point chosen on a shape's surface as seen from a reference point, with density `pdf` per unit solid angle at
/// the reference point (0: no sample).
struct ShapeDirectSample {
    Vec3d p{0.0};
    Vec3d n{0, 0, 1};
    Vec2d uv{0.0};
    double pdf = 0;
};

class Shape : public Object {
public:
    /// World-space geometry; called once when the scene is built.
    virtual ShapeGeometry geometry() const = 0;
    /// Surface area in world space (for emitters and diagnostics).
    virtual double surface_area() const = 0;
    /// A point uniformly distributed over the surface (pdf = 1 / area), with the shape's oriented normal.
    virtual PositionSample sample_position(const Vec2d& u) const = 0;

    /// A point of the surface chosen as seen from `ref` (an area light's next-event estimation), its density per
    /// unit solid angle at `ref`. The default: sample_position() converted, pdf_A d^2 / |cos| (pdf 0 where the point
    /// is `ref` itself). A sphere seen from outside samples the cone it subtends instead (samples_solid_angle()).
    virtual ShapeDirectSample sample_direction(const Vec3d& ref, const Vec2d& u) const;
    /// The solid-angle density at q.ref with which sample_direction() chooses the point q.p (normal q.n) in the unit
    /// direction q.d; the caller has checked that the surface faces q.ref (q.d . q.n != 0).
    virtual double pdf_direction(const DirectQuery& q) const;
    /// True where sample_direction() is not sample_position() converted to solid angle (for any reference point).
    virtual bool samples_solid_angle() const { return false; }

    /// Mitsuba's mesh attributes ("vertex_color", "face_weight", ...): the value at `si` (vertex attributes
    /// interpolated, face attributes constant per face), 1 channel as grey. False when the shape has none by
    /// that name.
    virtual bool eval_attribute(std::string_view name, const SurfaceInteraction& si, Color3& out) const {
        return false;
    }
    virtual bool has_attribute(std::string_view name) const { return false; }

    const Bsdf* bsdf() const { return m_bsdf.get(); }
    /// Media on the two sides (Mitsuba's `interior` and `exterior`): the interior is on the side opposite the
    /// geometric normal. Null when not given (a ray crossing keeps its medium unless the shape has either).
    const Medium* interior() const { return m_interior.get(); }
    const Medium* exterior() const { return m_exterior.get(); }
    bool is_medium_transition() const { return m_interior || m_exterior; }
    /// Where the interior medium was given (for the scene's error when the shape is not closed).
    const SourceLoc& interior_location() const { return m_interior_loc; }
    const Emitter* emitter() const { return m_emitter.get(); }
    Emitter* emitter() { return m_emitter.get(); }

protected:
    /// Reads the common nested objects: <bsdf> (default: diffuse) and <emitter> (optional). Every shape
    /// plugin declares them with param::object("bsdf", "bsdf", ...) and param::object("emitter", "emitter", ...),
    /// and the media with KELVIN_SHAPE_MEDIA_PARAMS.
    void read_common(const Properties& props);

    std::shared_ptr<Bsdf> m_bsdf;
    std::shared_ptr<Emitter> m_emitter;
    std::shared_ptr<Medium> m_interior, m_exterior;
    SourceLoc m_interior_loc;
};

/// Mitsuba's `shapegroup`: shapes declared once, under an id, and placed in the scene only by `instance`s (the
/// group itself is not rendered). Its shapes keep their own BSDFs; area emitters, media and nested groups or
/// instances are refused when the group is built.
class ShapeGroup : public Object {
public:
    explicit ShapeGroup(std::vector<std::shared_ptr<Shape>> shapes) : m_shapes(std::move(shapes)) {}
    const std::vector<std::shared_ptr<Shape>>& shapes() const { return m_shapes; }

private:
    std::vector<std::shared_ptr<Shape>> m_shapes;
};

/// Mitsuba's `instance`: a shape group placed by an affine `to_world`. The scene traces it as an Embree instance
/// of the group's geometry, which is built once however many instances use it.
class ShapeInstance : public Object {
public:
    ShapeInstance(std::shared_ptr<const ShapeGroup> group, const Transform& to_world)
        : m_group(std::move(group)), m_to_world(to_world) {}
    const ShapeGroup& group() const { return *m_group; }
    const std::shared_ptr<const ShapeGroup>& group_ptr() const { return m_group; }
    const Transform& to_world() const { return m_to_world; }

private:
    std::shared_ptr<const ShapeGroup> m_group;
    Transform m_to_world;
};

}  // namespace kelvin

/// The media parameters every shape declares (append to its KELVIN_PLUGIN parameter list).
#define KELVIN_SHAPE_MEDIA_PARAMS                                                                 \
    kelvin::param::object("interior", "medium", "medium inside the shape (opposite the normal)"), \
        kelvin::param::object("exterior", "medium", "medium outside the shape (on the normal's side)")
