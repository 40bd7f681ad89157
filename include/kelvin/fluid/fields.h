#pragma once
// Plugin interfaces of the fluid solver: initial vorticity fields (<vorticity>), smoke (<scalar>) and caches
// (<cache>); velocity estimators (<velocity>) are in velocity.h. Concrete plugins live in src/plugins/fluid/, one file
// each.
#include <kelvin/core/object.h>
#include <kelvin/fluid/biot_savart.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/grid3.h>
#include <kelvin/fluid/velocity.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

namespace kelvin::fluid {

/// True when `length` is a whole number (>= 1) of `period`s: a periodic box that fits a periodic field exactly.
inline bool fits_period(double length, double period) {
    const double r = length / period;
    return std::abs(r - std::nearbyint(r)) < 1e-6 * std::max(1.0, r) && std::nearbyint(r) >= 1;
}

/// An initial vorticity field omega(0, x) (<vorticity type="...">).
class VorticityField : public Object {
public:
    virtual double vorticity(const Vec2d& x) const = 0;
    /// The exact solution of the flow this field starts, where one is known: free space for vortices,
    /// the periodic box for Taylor–Green (see docs/fluid.md). Used by tests and diagnostics.
    virtual std::optional<double> exact_vorticity(double t, const Vec2d& x, double viscosity) const {
        return std::nullopt;
    }
    virtual std::optional<Vec2d> exact_velocity(double t, const Vec2d& x, double viscosity) const {
        return std::nullopt;
    }
    /// Whether exact_vorticity is the solution of the flow on `domain` (without solid boundaries): Taylor–Green
    /// on periodic boxes that fit its period, vortices in open (free-space) domains.
    virtual bool exact_on(const Domain2& domain) const { return false; }
    /// Called once with the simulation's domain before any other call, by every simulation: fields placed
    /// relative to the box (bitmap, vortex_sheet's wavelength) record it here.
    virtual void bind_domain(const Domain2& domain) {}
    /// Called once with the simulation's domain: raise an InputError (through the plugin's Properties,
    /// kept for that purpose) or log a warning when the field does not suit the domain.
    virtual void check_domain(const Domain2& domain) const {}
    /// One line for the run summary ("taylor_green(amplitude=1, k=1)").
    virtual std::string description() const = 0;
    /// The parameter that scales the field ("circulation", "amplitude"): what an error names when the initial
    /// state is too strong to be represented (fluid/checks.h). Empty: not known.
    virtual std::string strength_parameter() const { return {}; }
};

/// An initial 3D vorticity field omega(0, x) (<vorticity type="..."> in a scene with dimension = 3). A 3D-only
/// plugin derives from Object and VorticityField3 (vortex_ring, abc); a field that exists in both dimensions
/// implements VorticityField and VorticityField3 (taylor_green). A scene of the other dimension refuses a plugin
/// that lacks its interface with a one-line error naming `vorticity`.
class VorticityField3 {
public:
    virtual ~VorticityField3() = default;
    virtual Vec3d vorticity3(const Vec3d& x) const = 0;
    /// The exact solution of the flow, where one is known (nullopt elsewhere, e.g. for t > 0).
    virtual std::optional<Vec3d> exact_vorticity3(double t, const Vec3d& x, double viscosity) const {
        return std::nullopt;
    }
    virtual std::optional<Vec3d> exact_velocity3(double t, const Vec3d& x, double viscosity) const {
        return std::nullopt;
    }
    /// One component of the exact solution by the convergence study's field name ("u", "v", "w",
    /// "vorticity_x/y/z"; Checkpointable::exact3); nullopt for other names or where no solution is known.
    std::optional<double> exact_component3(const std::string& name, double t, const Vec3d& x, double viscosity) const {
        const bool vort = name.rfind("vorticity_", 0) == 0;
        const std::optional<Vec3d> e = vort ? exact_vorticity3(t, x, viscosity) : exact_velocity3(t, x, viscosity);
        if (!e) return std::nullopt;
        const char c = vort ? name.back() : name == "u" ? 'x' : name == "v" ? 'y' : name == "w" ? 'z' : '?';
        if (c == '?') return std::nullopt;
        return c == 'x' ? e->x : c == 'y' ? e->y : e->z;
    }
    /// Called once with the simulation's domain: raise an InputError or log a warning when the field does not
    /// suit the domain.
    virtual void check_domain3(const Domain3& domain) const {}
    virtual std::string description3() const = 0;
    /// As VorticityField::strength_parameter.
    virtual std::string strength_parameter3() const { return {}; }
};

/// Coaxial vortex rings as an initial field (vortex_ring): their geometry, for diagnostics that follow each ring's
/// core (ring_cores.h). A VorticityField3 plugin that is such rings derives from this interface too; the
/// simulations find it by dynamic_cast, so fields that are not rings are unaffected.
struct RingGeometry {
    Vec3d center{0.0};            ///< the first ring's centre
    Vec3d normal{0.0, 0.0, 1.0};  ///< unit axis, the direction a ring of positive circulation moves in
    double radius = 1, circulation = 1, core = 0.1;
    std::vector<double> offsets;  ///< the rings' centres along the normal, relative to `center`
};
class VortexRings3 {
public:
    virtual ~VortexRings3() = default;
    virtual RingGeometry ring_geometry() const = 0;
};

/// A 3D smoke source (<scalar type="smoke"> in a scene with dimension = 3): a passive density advected along the
/// solver's own backtraces, initialised and fed inside a sphere.
class SmokeSpec3 : public Object {
public:
    virtual Vec3d center() const = 0;
    virtual double radius() const = 0;
    /// Density inside the sphere at t = 0.
    virtual double initial_density() const = 0;
    /// Density added per unit time inside the sphere (0: no source after t = 0).
    virtual double rate() const = 0;
    virtual std::string description() const = 0;
};

// Velocity estimators (<velocity type="...">) implement VelocityEstimator (velocity.h): the built-in
// biot_savart (estimators.h) and walk_on_spheres (boundary.h), and any plugin.

/// A field cache (<cache type="grid">).
class CacheSpec : public Object {
public:
    /// Cells along x; cells along y (0: chosen for square cells on the domain).
    virtual int resolution_x() const = 0;
    virtual int resolution_y() const = 0;
    /// Cells along z in 3D (0: chosen for cubic cells on the domain).
    virtual int resolution_z() const { return 0; }
    virtual Interpolation interpolation() const = 0;
};

}  // namespace kelvin::fluid
