#pragma once
// Velocity estimators (<velocity type="...">): the interface through which the Monte Carlo fluid solvers
// (MCFluidSolver in mcfluid.h, MCFluid3Solver in mcfluid3.h) estimate the velocity of a state.
//
// Two objects, because a solver's state changes every step while the scene's choice does not:
//
//   VelocityEstimator  the plugin (one per scene): its parameters, which dimensions it supports, and build2() /
//                      build3(), which turn the vorticity cache of one state into a field;
//   VelocityField2/3   the velocity of one state (built once per step, immutable, shared by every thread):
//                      estimate(x, n, rng, walks) returns a Monte Carlo estimate at x with n samples.
//
// The solvers call estimate() once per query point (cell centres, RK stage points, stretching segment ends), so
// the cost of the virtual call is amortised over n samples: an estimator keeps its sample loop (and any
// vectorisation) inside estimate(). Determinism is the solver's business: every query receives its own
// counter-based Random stream, so an estimate must depend only on (x, n, the draws from rng), never on shared
// mutable state or on the thread.
//
// The built-in estimators are BiotSavartVelocity (biot_savart: free space and periodic domains, 2D and 3D) and
// WosVelocity (walk_on_spheres, boundary.h: solid boundaries by Walk-on-Spheres). A plugin derives from
// VelocityEstimator, and from VelocityField2 (or 3) for its field, in one file; see docs/fluid.md ("Writing a
// velocity estimator") and examples/plugins/uniform_biot_savart.cpp.
#include <kelvin/core/interrupt.h>
#include <kelvin/core/math.h>
#include <kelvin/core/object.h>
#include <kelvin/core/random.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/grid3.h>

#include <memory>
#include <string>

namespace kelvin::wos {
struct WalkCounters;  // wos/wos.h
}

namespace kelvin::fluid {

class PeriodicKernel;   // biot_savart.h
class PeriodicKernel3;  // biot_savart3.h
struct WosVelocityOptions;
class WosVelocityField;
class WosVelocityField3;

/// A velocity estimate with the variance of the estimate itself (sample variance / n), per component.
struct VelocityEstimate {
    Vec2d value{0.0};
    Vec2d variance{0.0};
    int samples = 0;  ///< kernel evaluations done (0 for an empty field)
};

/// The same in 3D.
struct VelocityEstimate3 {
    Vec3d value{0.0};
    Vec3d variance{0.0};
    int samples = 0;  ///< kernel evaluations done (0 for an empty field)
};

/// What a 2D solver hands an estimator to build the velocity of one state.
struct VelocityState2 {
    Domain2 domain;
    /// The vorticity cache omega_h at the cell centres; it outlives the field built from it.
    const Grid2* omega = nullptr;
    Interpolation interpolation = Interpolation::Bilinear;  ///< how omega_h is read between cell centres
    double delta = 0;  ///< mollifier radius, resolved by the solver (VelocityEstimator::delta() < 0: half a cell)
    double time = 0;   ///< the state's time (moving solids are placed at it)
    /// The doubly periodic kernel correction on periodic domains without solid boundaries (null otherwise);
    /// shared by every state, built once by the solver.
    std::shared_ptr<const PeriodicKernel> periodic;
    /// The solver whose passes query the field (null: never stopped): an estimate with many samples polls its
    /// stop_requested() within the sample loop (every few thousand samples, every 64 walks) and returns early;
    /// the solver then discards the whole pass, so the early value is never used. It outlives the field.
    const Cancellable* stop = nullptr;
    /// The solver's seed and a random stream of this state, for work an estimator does once per state (the
    /// harmonic cache of walk_on_spheres): distinct for every step.
    uint64_t seed = 0, stream = 0;
    /// The samples per query the solver will ask for (0: the estimator's own samples()).
    int samples = 0;
};

/// What the 3D solver hands an estimator to build the velocity of one state (or of the difference of two
/// consecutive states, with control variates).
struct VelocityState3 {
    Domain3 domain;
    const VectorGrid3* omega = nullptr;                     ///< omega_h at the cell centres (outlives the field)
    Interpolation interpolation = Interpolation::Bilinear;  ///< Bilinear means trilinear
    double delta = 0;                                       ///< resolved mollifier radius
    std::shared_ptr<const PeriodicKernel3> periodic;        ///< as in VelocityState2
    /// True when omega is the difference of two consecutive states (control variates, Eq. 5.23): any boundary
    /// data of the two states cancel (a Walk-on-Spheres field takes Psi = 0 on every boundary).
    bool difference = false;
    const Cancellable* stop = nullptr;  ///< as in VelocityState2
    uint64_t seed = 0, stream = 0;      ///< as in VelocityState2
    int samples = 0;                    ///< as in VelocityState2
};

/// The velocity of one 2D state. Immutable once built; estimate() is called concurrently from many threads.
class VelocityField2 {
public:
    virtual ~VelocityField2() = default;
    /// A Monte Carlo estimate of the velocity at x with n samples drawn from rng only. `walks`: Walk-on-Spheres
    /// work counters (estimators without walks leave them alone). A non-finite value or variance is counted
    /// and replaced by zero by the solver.
    virtual VelocityEstimate estimate(Vec2d x, int n, Random& rng, wos::WalkCounters& walks) const = 0;
    /// The solid boundaries this field respects (walk_on_spheres): the solver moves departure points out of
    /// solids and reflects diffusion samples off walls with them. Null (the default): free space or periodic.
    virtual const WosVelocityField* boundaries() const { return nullptr; }
};

/// The velocity of one 3D state (see VelocityField2).
class VelocityField3 {
public:
    virtual ~VelocityField3() = default;
    virtual VelocityEstimate3 estimate(Vec3d x, int n, Random& rng, wos::WalkCounters& walks) const = 0;
    virtual const WosVelocityField3* boundaries() const { return nullptr; }
};

/// A velocity estimator plugin (<velocity type="...">).
class VelocityEstimator : public Object {
public:
    /// n_mc, the samples per velocity query (`kelvin --spp` overrides it).
    virtual int samples() const = 0;
    /// The mollifier radius the solver resolves into VelocityState::delta: < 0 means half a cache cell.
    virtual double delta() const { return -1; }
    /// Whether build2() (dimension 2) or build3() (dimension 3) is implemented. A scene of a dimension the
    /// estimator does not support is refused with a one-line error naming `velocity`.
    virtual bool supports(int dimension) const = 0;
    /// Why the estimator cannot run on `domain` ("" when it can); the simulation reports it as an error naming
    /// `velocity` (e.g. an estimator for open domains given a periodic one).
    virtual std::string check2(const Domain2& domain) const { return {}; }
    virtual std::string check3(const Domain3& domain) const { return {}; }
    /// The field of one state. Called once per step (and once per velocity pass with control variates), from
    /// one thread. The defaults throw: override the one of each supported dimension.
    virtual std::unique_ptr<VelocityField2> build2(const VelocityState2& state) const;
    virtual std::unique_ptr<VelocityField3> build3(const VelocityState3& state) const;
    /// The solid boundaries of the scene, when the estimator handles them (walk_on_spheres); null otherwise.
    virtual std::shared_ptr<const WosVelocityOptions> boundaries() const { return nullptr; }
    /// One phrase for the run summary, e.g. "Biot–Savart velocity (n_mc 256, importance vorticity, delta
    /// 0.03)"; `samples` and `delta` are the values the solver uses.
    virtual std::string effect(int samples, double delta, bool periodic) const;
};

}  // namespace kelvin::fluid
