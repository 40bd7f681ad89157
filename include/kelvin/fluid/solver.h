#pragma once
// The interface of a 2D fluid solver as the run loop and a host application see it: stepping, the fields of the
// current state on the solver's grid, pointwise queries, diagnostics and counters. mcfluid's MCFluidSolver and
// the baselines (stable_fluids, vortex_particles) implement it; a host gets one from a loaded scene through
// Simulation::create_solver (simulation.h, docs/host-api.md).
//
// Cancellation: step() and the velocity passes poll stop_requested() (Cancellable, core/interrupt.h): the token
// set with set_cancel_token() or a process-wide interrupt. A stopped step returns false and keeps the state.
#include <kelvin/core/interrupt.h>
#include <kelvin/core/math.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/grid.h>

#include <cstdint>
#include <limits>

namespace kelvin::fluid {

class PassiveScalars;  // dye.h

/// Integral diagnostics of one state (integrals over the domain box, midpoint rule on the cells).
struct FluidDiagnostics {
    long long step = 0;
    double time = 0;
    double kinetic_energy = 0;      ///< 1/2 int |u|^2, minus the estimated Monte Carlo noise energy
    double kinetic_energy_raw = 0;  ///< 1/2 int |u_hat|^2 of the noisy estimate
    double enstrophy = 0;           ///< 1/2 int omega^2
    double circulation = 0;         ///< int omega
    double max_abs_vorticity = 0;
    /// RMSE of the vorticity at the cell centres against the initial condition's exact solution (NaN: none
    /// known; see exact_vorticity_rmse in output.h).
    double vorticity_rmse_exact = std::numeric_limits<double>::quiet_NaN();
};

/// A 2D solver. Fields are on its grid (nx x ny cell centres of the domain).
class FluidSolver : public Cancellable {
public:
    virtual ~FluidSolver() = default;
    virtual double time() const = 0;
    virtual long long step_index() const = 0;
    /// One step of length dt; false (state unchanged) when the cancel token or a process-wide interrupt
    /// stopped it.
    virtual bool step(double dt) = 0;
    virtual const Grid2& vorticity_grid() = 0;
    virtual const Grid2& velocity_u() = 0;
    virtual const Grid2& velocity_v() = 0;
    /// Whether the grids above describe the current state: false when a stop (interrupt, time limit) cut the pass
    /// that computes them (vortex_particles' initial state); the grids then hold what the solver documents.
    virtual bool fields_available() { return true; }

    /// omega at x for the current state: by default the vorticity grid interpolated bilinearly (the solver's own
    /// interpolation for mcfluid). Periodic domains wrap x; open ones give 0 outside the box.
    virtual double vorticity_at(Vec2d x);
    /// The velocity at x for the current state: by default the cell-centre velocity grids interpolated
    /// bilinearly. mcfluid gives a fresh Monte Carlo estimate with the solver's n_mc samples, on a random stream
    /// fixed by (seed, step, x), so the same query gives the same answer; vortex_particles sums the particles.
    virtual Vec2d velocity_at(Vec2d x);

    /// Energy, enstrophy, circulation and max |omega| of the fields above (energy_raw = energy: no noise).
    virtual FluidDiagnostics diagnostics();
    virtual PassiveScalars* dye() = 0;
    /// Kernel evaluations so far (the CSV's biot_savart_evals column: particle pairs; 0 for grid solvers).
    virtual double evaluations() const = 0;
    /// Non-finite values met so far (replaced by zero).
    virtual uint64_t invalid() const = 0;
    /// Counters and timers into `stats` (fluid.*).
    virtual void report(Stats& stats) const = 0;
};

}  // namespace kelvin::fluid
