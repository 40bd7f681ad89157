#pragma once
// The <boundary> plugins' interface (src/plugins/boundaries/): a boundary is a distance provider for Walk-on-Spheres
// (wos.h) in 2D or 3D, plus the role it plays in a problem (the value on it, how it moves, on which side the domain
// lies). Solvers (the fluid's free-slip velocity, the wos_poisson plugin) take a list of them. See
// docs/boundaries.md.
//
// Geometry: analytic shapes, polylines and triangle meshes (through the renderer's closest-point queries), OpenVDB
// level sets, unsigned distances. Shapes that know their inside (analytic shapes, closed polygons, signed level sets)
// also answer inside(); unsigned ones (open polylines, triangle soups, unsigned grids) have no inside, and a domain
// simply surrounds (and, through holes, enters) them.
//
// A plugin: one class per dimension, derived from Boundary2 or Boundary3 (which make it its own distance provider),
// registered with KELVIN_BOUNDARY_PLUGIN (one class, or ByDimension<C2, C3> for a name that exists in both
// dimensions), which appends the common parameters (with_boundary_params) to the plugin's own.
#include <kelvin/core/object.h>
#include <kelvin/core/properties.h>
#include <kelvin/core/registry.h>
#include <kelvin/wos/wos.h>

#include <array>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace kelvin::wos {

/// What a solver needs to know about a boundary besides its geometry (the common <boundary> parameters).
struct BoundaryRole {
    double stream_value = 0;          ///< the Dirichlet value on the boundary (the fluid's isovalue psi_0; at the pivot
                                      ///< if moving)
    Vec2d velocity{0.0};              ///< rigid translation velocity U
    double angular_velocity = 0;      ///< rigid rotation rate Omega (radians per unit time, counter-clockwise)
    Vec2d pivot{0.0};                 ///< rotation centre at t = 0 (moves with U)
    bool fluid_inside = false;        ///< the domain is inside the shape (a container) instead of outside (an obstacle)
    bool stream_value_given = false;  ///< the scene set stream_value (else the default 0 was taken)
    bool moving() const { return velocity != Vec2d(0.0) || angular_velocity != 0; }
};

/// A boundary geometry (<boundary type="...">).
class BoundaryShape : public Object {
public:
    /// 2 or 3.
    virtual int dimension() const = 0;
    /// The distance provider (non-null for the shape's dimension).
    virtual const BoundaryGeometry<2>* geometry2() const { return nullptr; }
    virtual const BoundaryGeometry<3>* geometry3() const { return nullptr; }
    /// Whether inside() means something (closed, oriented or signed shapes).
    virtual bool has_inside() const { return false; }
    /// p lies in the shape's interior (only when has_inside()).
    virtual bool inside2(const Vec2d& p) const { return false; }
    virtual bool inside3(const Vec3d& p) const { return false; }
    /// Axis-aligned bounds of the boundary (for messages and checks).
    virtual std::pair<Vec3d, Vec3d> bounds() const = 0;
    /// One line for the run summary.
    virtual std::string description() const = 0;
    /// A 2D shape as straight segments, curved pieces cut into chords no longer than `max_length`: what methods that
    /// discretise the boundary need (the panel method of the vortex_particles baseline, fluid/panels.h). Empty when
    /// the shape cannot give them (3D shapes, unsigned grids).
    virtual std::vector<std::array<Vec2d, 2>> segments2(double max_length) const { return {}; }

    const BoundaryRole& role() const { return m_role; }
    /// The solid region of a 2D shape: inside an obstacle, outside a container (false without has_inside()).
    bool solid2(const Vec2d& p) const { return has_inside() && (inside2(p) != m_role.fluid_inside); }

protected:
    /// Reads the common parameters (with_boundary_params). `has_inside`: whether `fluid="inside"` is allowed.
    BoundaryShape(const Properties& props, bool has_inside);
    BoundaryRole m_role;
};

/// A 2D boundary plugin that is its own distance provider.
class Boundary2 : public BoundaryShape, public BoundaryGeometry<2> {
public:
    int dimension() const override { return 2; }
    const BoundaryGeometry<2>* geometry2() const override { return this; }

protected:
    Boundary2(const Properties& props, bool has_inside) : BoundaryShape(props, has_inside) {}
};

/// A 3D boundary plugin that is its own distance provider.
class Boundary3 : public BoundaryShape, public BoundaryGeometry<3> {
public:
    int dimension() const override { return 3; }
    const BoundaryGeometry<3>* geometry3() const override { return this; }

protected:
    Boundary3(const Properties& props, bool has_inside) : BoundaryShape(props, has_inside) {}
};

/// The parameters every <boundary> plugin takes, appended to its own.
std::vector<ParamSpec> with_boundary_params(std::vector<ParamSpec> own);

/// Parses "x y, x y, ..." (commas or semicolons between points) into 2D points; errors name `param`.
std::vector<Vec2d> parse_points2(const Properties& props, const std::string& param);

/// Why a boundary's bounds are beyond what its queries resolve (|coordinate| > 1e17, or not finite); empty when fine.
std::string check_boundary_extent(const BoundaryShape& shape);

/// The `dimension` parameter of a plugin that exists in 2D and 3D: 2 or 3 (an error naming it otherwise).
int read_dimension(const Properties& props);

/// A <boundary> plugin with one class per dimension, chosen by its `dimension` parameter (declare it among the
/// plugin's own parameters): C2 for 2, C3 for 3.
template <class C2, class C3>
struct ByDimension {
    static ObjectPtr create(const Properties& props) {
        if (read_dimension(props) == 2) return std::make_shared<C2>(props);
        return std::make_shared<C3>(props);
    }
};

/// The factory KELVIN_BOUNDARY_PLUGIN registers: `Class::create` when it has one (ByDimension), else the constructor.
template <class Class>
ObjectPtr make_boundary(const Properties& props) {
    if constexpr (requires { Class::create(props); })
        return Class::create(props);
    else
        return std::make_shared<Class>(props);
}

}  // namespace kelvin::wos

/// Registers a <boundary> plugin: like KELVIN_PLUGIN, with the common boundary parameters appended. `Class` is the
/// plugin's class, or kelvin::wos::ByDimension<C2, C3> (through an alias) for one name in 2D and 3D.
#define KELVIN_BOUNDARY_PLUGIN(Class, name, doc, ...)                                                              \
    static const ::kelvin::PluginRegistrar KELVIN_CONCAT(kelvin_registrar_, __LINE__)(                             \
        "boundary", name, doc, ::kelvin::wos::with_boundary_params(std::vector<::kelvin::ParamSpec>{__VA_ARGS__}), \
        &::kelvin::wos::make_boundary<Class>)
